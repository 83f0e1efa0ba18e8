"""Trajectory control of the two-axis bench: ellipse references, inverse-model feedforward, PID
(paper eq. 19), harmonic ILC, safety checks, and the period-by-period runner (compiled per sample).

Entry point: ``service.control.session.track(bench, Ellipse(...), Controller(...), mode)``.
"""
