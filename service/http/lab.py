"""The lab of benches (several services on one store): GET /api/lab/benches, GET /api/lab/compare."""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter, Depends, Query

from service.http.deps import get_store
from service.http.schemas.lab import LabBenches, LabComparison
from service.store import Store
from service.usecases import lab

router = APIRouter(prefix="/lab", tags=["lab"])


@router.get("/benches", response_model=LabBenches)
def lab_benches(store: Store = Depends(get_store)) -> dict:
    """Every bench registered on this store: its state, ``online`` (false once stopped or silent for
    ``offline_after_heartbeats`` heartbeat intervals), last heartbeat, running job, how many datasets
    it holds and its newest model per axis (effects, held-out RMS, noise floor)."""
    return lab.benches(store)


@router.get("/compare", response_model=LabComparison)
def lab_compare(
    axis: Literal["y", "z"] = Query(..., description="the axis whose newest models are compared"),
    store: Store = Depends(get_store),
) -> dict:
    """Per bench, its newest model of ``axis``: effects, held-out RMS, noise floor and the physical
    parameters discovery fitted (resonance Hz and damping, creep per decade, delay µs, drift,
    coupling), so a stage that differs or drifts stands out. 422 naming ``axis`` otherwise."""
    return lab.compare(store, axis)
