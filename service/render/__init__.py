"""The model report's rendering (GET /api/models/{id}/report, service.usecases.report): the HTML page
(model_report.py) with its SVG charts (svg.py) and the commands that reproduce the model
(reproduce.py). Strings from numbers: no store, no HTTP, no science."""
