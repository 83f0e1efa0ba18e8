"""Reports: scripts that regenerate docs/ (reproduction, calibration, discovery, tracking), and the
model report (model_report: one HTML file with SVG charts, svg; its reproduce commands, reproduce)."""
