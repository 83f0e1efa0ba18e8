"""Trajectory control of the two-axis bench: ellipse references, inverse-model feedforward (static PI,
or a discovery composite model: every model inverts itself), PID (paper eq. 19), harmonic ILC, safety checks
(including the stroke), and the period-by-period runner (compiled per sample).

Entry point: ``service.science.control.session.track(bench, Ellipse(...), Controller(...), mode)``.
"""
