"""The model report: GET /api/models/{id}/report, one self-contained HTML file (service.usecases.report)."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query
from fastapi.responses import HTMLResponse

from drivers.bench import Bench
from service.http.deps import get_bench, get_store
from service.http.schemas.models import ReportFigures
from service.runtime.bulk import run_bulk
from service.store import Store
from service.usecases.acquire import BenchExperiments
from service.usecases.report import model_figures, model_report

router = APIRouter(prefix="/models", tags=["reports"])

#: HTML has no response model: the OpenAPI document names its media type and says what it holds
REPORT_RESPONSES = {
    200: {
        "content": {"text/html": {"schema": {"type": "string"}}},
        "description": "the report: one HTML file with inline SVG figures, no script",
    },
    404: {"description": "no model with that id"},
}


@router.get("/{model_id}/report", response_class=HTMLResponse, responses=REPORT_RESPONSES)
async def get_report(
    model_id: str,
    download: bool = Query(False, description="answer as an attachment (<model-id>-report.html)"),
    store: Store = Depends(get_store),
    bench: Bench = Depends(get_bench),
) -> HTMLResponse:
    """The model as one self-contained HTML page: the model, its datasets, the lineage with the RMS of
    each step, the diagnosis (verdict, noise floor, candidates with evidence, what the data cannot
    test), the fitted parameters, per block the loop and the residual over the held-out cycles and the
    error history (inline SVG), and the curl / evcbench / Python commands that reproduce it. It runs
    a diagnosis, so it takes as long as GET /api/models/{id}/diagnosis. Print it from a browser for a
    PDF (the figures stay vectors)."""
    html = await run_bulk(model_report, store, model_id, BenchExperiments(bench))
    headers = {"Content-Disposition": f'attachment; filename="{model_id}-report.html"'} if download else {}
    return HTMLResponse(html, headers=headers)


@router.get("/{model_id}/report/figures", response_model=ReportFigures)
async def get_report_figures(model_id: str, store: Store = Depends(get_store)) -> dict:
    """The report's figures alone, as the report draws them: the error history and, per block, its
    name, held-out RMS and SVG (the held-out loop and residual), the block the diagnosis names worst
    marked. For a page to inline; it runs a diagnosis, as the report does."""
    return await run_bulk(model_figures, store, model_id)
