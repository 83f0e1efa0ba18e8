"""Datasets: import (multipart CSV), list, describe, and export (JSON, CSV, HDF5)."""
from __future__ import annotations

import math
from typing import Literal

import numpy as np
from fastapi import APIRouter, Depends, File, Form, HTTPException, Query, UploadFile
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool

from service.api.deps import get_store
from service.datasets import DataError, parse_table, to_csv, to_hdf5, units_for
from service.segmentation import blocks_without_table
from service.store import Store

router = APIRouter(prefix="/datasets", tags=["datasets"])

MAX_UPLOAD_BYTES = 200 * 1024 * 1024
SUMMARY_KEYS = ("id", "name", "source", "axes", "samples", "sample_rate_hz", "partial", "partial_reason",
                "created_at", "started_at", "finished_at", "job_id")


def dataset_view(row: dict, full: bool = True) -> dict:
    """A dataset record as the API shows it (units in the field names)."""
    view = {k: row[k] for k in SUMMARY_KEYS}
    view["duration_s"] = row["samples"] / row["sample_rate_hz"]
    view["n_blocks"] = len(row["blocks"])
    if full:
        view.update(blocks=row["blocks"], plan=row["plan"], config=row["config"], units=row["units"],
                    software_version=row["software_version"], file=row["file"], sha256=row["sha256"])
    return view


@router.post("", status_code=201)
async def import_dataset(
    file: UploadFile = File(..., description="CSV (header t,u_y,x_y,… or u,x) or a headerless table"),
    name: str | None = Form(None, max_length=200),
    axis: str | None = Form(None, description="y or z, for single-axis files with columns u, x"),
    columns: str | None = Form(None, description='JSON mapping, e.g. {"u": 0, "x": 4} (0-based)'),
    sample_rate_hz: float | None = Form(None, description="needed when the file has no t column"),
    delimiter: str | None = Form(None, description="comma | tab | semicolon | whitespace (default: guess)"),
    store: Store = Depends(get_store),
) -> dict:
    """Import a table as a dataset: ``201 {"id", "axes", "samples", "sample_rate_hz", …}``.

    Refused with 422 naming the field or column at fault (malformed rows, NaN, volts outside
    0–120 V, …); nothing is stored then.
    """
    content = await file.read(MAX_UPLOAD_BYTES + 1)
    if len(content) > MAX_UPLOAD_BYTES:
        raise HTTPException(413, detail=f"file: larger than {MAX_UPLOAD_BYTES // 2**20} MiB")
    if sample_rate_hz is not None and not math.isfinite(sample_rate_hz):
        raise DataError("sample_rate_hz", "must be a finite number of hertz")
    options = {"filename": file.filename, "columns": columns, "axis": axis, "sample_rate_hz": sample_rate_hz,
               "delimiter": delimiter}
    return await run_in_threadpool(_import, store, content, name or file.filename or "imported", options)


def _import(store: Store, content: bytes, name: str, options: dict) -> dict:
    """Parse, validate and store (off the event loop)."""
    table = parse_table(content, columns=options["columns"], axis=options["axis"],
                        sample_rate_hz=options["sample_rate_hz"], delimiter=options["delimiter"])
    blocks = blocks_without_table({a: table.arrays[f"u_{a}_v"] for a in table.axes}, table.sample_rate_hz)
    row = store.add_dataset(table.arrays, {
        "name": name, "source": "import", "axes": table.axes, "sample_rate_hz": table.sample_rate_hz,
        "blocks": blocks, "units": units_for(table.arrays), "plan": {"import": options}})
    return dataset_view(row)


@router.get("")
def list_datasets(store: Store = Depends(get_store)) -> list[dict]:
    """Every dataset, oldest first (summary fields)."""
    return [dataset_view(row, full=False) for row in store.list_datasets()]


@router.get("/{dataset_id}")
def get_dataset(dataset_id: str, store: Store = Depends(get_store)) -> dict:
    """A dataset's metadata: block table, plan, bench configuration snapshot, units, checksum."""
    return dataset_view(store.get_dataset(dataset_id))


@router.get("/{dataset_id}/data", response_model=None)
def get_dataset_data(dataset_id: str, format: Literal["json", "csv", "hdf5"] = "json",
                     max_points: int | None = Query(None, ge=2, description="json: decimate to about this many"),
                     store: Store = Depends(get_store)) -> dict | Response:
    """The samples: JSON arrays (``t_s``, ``u_y_v``, ``x_y_um``, …), CSV (DESIGN §4) or HDF5."""
    row = store.get_dataset(dataset_id)
    arrays = store.load_arrays(dataset_id)
    if format == "csv":
        return Response(to_csv(arrays), media_type="text/csv", headers=_attachment(dataset_id, "csv"))
    if format == "hdf5":
        meta = {k: row[k] for k in ("id", "name", "source", "sample_rate_hz", "blocks", "plan", "config",
                                    "units", "software_version", "created_at", "partial", "sha256")}
        return Response(to_hdf5(arrays, meta), media_type="application/x-hdf5",
                        headers=_attachment(dataset_id, "h5"))
    stride = max(1, math.ceil(row["samples"] / max_points)) if max_points else 1
    return {"id": dataset_id, "sample_rate_hz": row["sample_rate_hz"], "stride": stride,
            "units": units_for(arrays), **{k: np.asarray(v)[::stride].tolist() for k, v in arrays.items()}}


def _attachment(dataset_id: str, extension: str) -> dict:
    return {"Content-Disposition": f'attachment; filename="{dataset_id}.{extension}"'}
