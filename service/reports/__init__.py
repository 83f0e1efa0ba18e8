"""Reports: scripts that regenerate docs/ (reproduction, calibration, discovery, tracking)."""
