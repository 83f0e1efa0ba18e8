"""Admin routes (``/api/admin/*``; the auth layer puts them behind the admin scope).

Fault injection on the emulated bench, for tests and drills::

    POST   /api/admin/faults  {"fault": "sensor_dropout", "axis": "z", "after_s": 0.4}  → 201, the fault
    GET    /api/admin/faults                                                           → armed and fired faults
    DELETE /api/admin/faults                                                           → clear them all

A fault fires ``after_s`` emulated seconds into the bench session (one sweep or trajectory) that
is running or starts next (drivers/emulated/faults.py); the job then fails with the reason, its
samples so far are stored as a partial dataset and the output is at 0 V.
"""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException

from drivers.bench import Bench
from drivers.emulated.faults import KINDS, FaultRequestError, FaultUnavailable
from service.http.deps import get_bench
from service.http.schemas.admin import Fault, FaultRequest, Faults, FaultsCleared
from service.science.errors import FieldError

router = APIRouter(prefix="/admin", tags=["admin"])


def _injector(bench: Bench):
    world = bench.parts.world
    if world is None:
        raise HTTPException(409, detail=f"fault injection needs the emulated bench; this one is {bench.parts.backend}")
    return world.faults


@router.post("/faults", status_code=201, response_model=Fault)
def add_fault(body: FaultRequest, bench: Bench = Depends(get_bench)) -> dict:
    """Schedule a fault in the emulator (422 names a bad fault or axis; 409 if this bench cannot have it)."""
    injector = _injector(bench)
    try:
        fault = injector.add(body.fault, body.axis, body.after_s)
    except FaultUnavailable as exc:
        raise HTTPException(409, detail=str(exc)) from None
    except FaultRequestError as exc:
        raise FieldError(exc.field, exc.message) from None
    return fault.as_dict()


@router.get("/faults", response_model=Faults)
def list_faults(bench: Bench = Depends(get_bench)) -> dict:
    """The scheduled faults (armed or fired, with the session time they fired at) and the known kinds."""
    injector = _injector(bench)
    return {"faults": injector.list(), "kinds": list(KINDS), "transports": sorted(injector.transports)}


@router.delete("/faults", response_model=FaultsCleared)
def clear_faults(bench: Bench = Depends(get_bench)) -> dict:
    """Remove every fault and clear latched device faults; ``notes`` says what cannot be undone."""
    injector = _injector(bench)
    count = len(injector.list())
    notes = injector.clear()
    return {"cleared": count, "notes": notes, "output_v": bench.output_v()}
