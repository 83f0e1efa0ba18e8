"""Identification machinery: bounded LS over design blocks, PSO, metrics, procedures."""
