"""The web dashboard: the static files of web/ under /web (index.html, ES modules, and the charting
library installed by npm into web/node_modules), and GET / sending a browser there.

The dashboard uses only the REST API and its event streams; this module holds no logic.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import RedirectResponse
from fastapi.staticfiles import StaticFiles

WEB_DIR = Path(__file__).resolve().parents[2] / "web"


def mount(app: FastAPI, web_dir: Path = WEB_DIR) -> None:
    """Serve ``web_dir`` at /web and redirect / to it (nothing is mounted if the folder is missing)."""
    if not web_dir.is_dir():
        return

    @app.get("/", include_in_schema=False)
    def dashboard() -> RedirectResponse:
        return RedirectResponse("/web/")

    app.mount("/web", StaticFiles(directory=web_dir, html=True), name="web")
