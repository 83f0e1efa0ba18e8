"""GET /api/paper: the seed paper's published figures (service/science/paper.py), so that the dashboard
shows them beside ours without a copy of its own."""

from __future__ import annotations

from fastapi import APIRouter

from service.http.schemas.paper import PaperFigures
from service.science import paper

router = APIRouter(tags=["paper"])


@router.get("/paper", response_model=PaperFigures)
def paper_figures() -> dict:
    """Table 6 (RMS errors, µm), the static PI's 1 Hz errors, weight sums and strokes, the FEM modes
    (Hz), the PID gains and the tracking cases with their measured maximum errors (µm)."""
    return paper.as_dict()
