"""Datasets: import (multipart CSV, parsed as a stream), list, describe, and download (streamed)."""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter, Depends, File, Form, HTTPException, Query, UploadFile
from fastapi.responses import StreamingResponse

from service.http.deps import get_store
from service.http.schemas.common import BENCH_FILTER, DatasetLabelsUpdate, Deleted, one_line, with_figures
from service.http.schemas.datasets import Dataset, DatasetSummary
from service.http.schemas.streams import DATASET_DOWNLOADS
from service.runtime.bulk import iterate_bulk, run_bulk
from service.science.data.datasets import SAMPLE_RATE_RANGE_HZ
from service.science.data.export import JSON_DEFAULT_MAX_POINTS
from service.science.errors import FieldError
from service.store import DatasetRow, Store
from service.usecases.exports import export_chunks
from service.usecases.imports import import_table

router = APIRouter(prefix="/datasets", tags=["datasets"])

MAX_UPLOAD_BYTES = 200 * 1024 * 1024
SUMMARY_KEYS = (
    "id",
    "name",
    "source",
    "axes",
    "samples",
    "sample_rate_hz",
    "partial",
    "partial_reason",
    "created_at",
    "started_at",
    "finished_at",
    "job_id",
    "tags",
    "notes",
    "bench_id",
)
MEDIA_TYPES = {
    "json": "application/json",
    "csv": "text/csv",
    "ndjson": "application/x-ndjson",
    "hdf5": "application/x-hdf5",
}
_RATE_TEXT = f"{SAMPLE_RATE_RANGE_HZ[0]:g} Hz – {SAMPLE_RATE_RANGE_HZ[1] / 1e6:g} MHz"


def dataset_view(row: DatasetRow, full: bool = True) -> dict:
    """A dataset record as the API shows it (units in the field names)."""
    view = {k: row[k] for k in SUMMARY_KEYS}
    view["duration_s"] = row["samples"] / row["sample_rate_hz"]
    view["n_blocks"] = len(row["blocks"])
    plan = row["plan"] if isinstance(row["plan"], dict) else {}
    # an import's file, in the list as on its page (the list named it by its name, the page by its file)
    view["import_filename"] = (plan.get("import") or {}).get("filename") if row["source"] == "import" else None
    # an experiment's sweep (a diagnosis's or a discover run's), told from one the user planned
    view["experiment_of"] = plan.get("experiment_of") if row["source"] == "sweep" else None
    if full:
        view.update(
            blocks=row["blocks"],
            plan=row["plan"],
            config=row["config"],
            units=row["units"],
            drive_range_v=plan.get("drive_range_v"),
            import_notes=plan.get("notes") or [],
            software_version=row["software_version"],
            file=row["file"],
            sha256=row["sha256"],
        )
    return view


@router.post("", status_code=201, response_model=Dataset)
@with_figures(rate_range=_RATE_TEXT, json_max_points=JSON_DEFAULT_MAX_POINTS)
async def import_dataset(
    file: UploadFile = File(..., description="CSV (header t,u_y,x_y,… or u,x) or a headerless table"),
    name: str | None = Form(None, max_length=200),
    axis: str | None = Form(None, description="y or z, for single-axis files with columns u, x"),
    columns: str | None = Form(
        None, description='JSON mapping, e.g. {"u": 0, "x": 4} (0-based); columns it does not name are ignored'
    ),
    sample_rate_hz: float | None = Form(None, description=f"needed when the file has no t column ({_RATE_TEXT})"),
    delimiter: str | None = Form(None, description="comma | tab | semicolon | whitespace (default: guess)"),
    store: Store = Depends(get_store),
) -> dict:
    """Import a table as a dataset: ``201 {{"id", "axes", "samples", "sample_rate_hz", "drive_range_v", …}}``.

    The file is parsed as a stream in a worker thread (numpy's parser, a block at a time). Refused
    with 422 naming the field or column at fault (``file``, ``columns``, ``axis``, ``delimiter``,
    ``sample_rate_hz``, ``t``, a column with NaN, …); the options and the first line are checked
    before any data row is read, so e.g. a headerless file without ``columns`` is refused at once.
    The sample rate, given or implied by a ``t`` column, must lie in {rate_range}. Measured data is
    not a command: any drive range is accepted (bipolar, above the bench's limits) and shown as
    ``drive_range_v``. Nothing is stored when a request is refused.
    """
    if file.size is not None and file.size > MAX_UPLOAD_BYTES:
        raise HTTPException(413, detail=f"file: larger than {MAX_UPLOAD_BYTES // 2**20} MiB")
    options = {
        "filename": file.filename,
        "columns": columns,
        "axis": axis,
        "sample_rate_hz": sample_rate_hz,
        "delimiter": delimiter,
    }
    if name is not None:
        try:
            one_line(name)
        except ValueError as exc:
            raise FieldError("name", str(exc)) from None
    default = " ".join((file.filename or "imported").split())  # a file name with line breaks, as one line
    row = await run_bulk(import_table, store, file.file, name or default or "imported", options)
    return dataset_view(row)


@router.get("", response_model=list[DatasetSummary])
def list_datasets(bench_id: str | None = BENCH_FILTER, store: Store = Depends(get_store)) -> list[dict]:
    """Every dataset of every bench of the lab (``bench_id``: that bench's), oldest first (summary fields)."""
    return [dataset_view(row, full=False) for row in store.list_datasets(bench_id)]


@router.get("/{dataset_id}", response_model=Dataset)
def get_dataset(dataset_id: str, store: Store = Depends(get_store)) -> dict:
    """A dataset's metadata: block table, plan, bench configuration snapshot, units, drive range
    per axis (``drive_range_v``, volts, for imports), checksum."""
    return dataset_view(store.get_dataset(dataset_id))


@router.patch("/{dataset_id}", response_model=Dataset)
def label_dataset(dataset_id: str, body: DatasetLabelsUpdate, store: Store = Depends(get_store)) -> dict:
    """Rename, tag or annotate a dataset (the fields given; its samples never change)."""
    return dataset_view(store.label_dataset(dataset_id, **body.model_dump(exclude_unset=True)))


@router.delete("/{dataset_id}", response_model=Deleted)
def delete_dataset(
    dataset_id: str,
    cascade: bool = Query(False, description="also delete the models fitted on it and every model refined from them"),
    store: Store = Depends(get_store),
) -> dict:
    """Delete a dataset and its arrays. Refused with 409 naming the models fitted on it (``dependents``)
    unless ``cascade=true``; the store stays consistent (``evcbench store check``)."""
    return store.delete_dataset(dataset_id, cascade)


@router.get("/{dataset_id}/data", response_model=None, responses=DATASET_DOWNLOADS)
@with_figures(rate_range=_RATE_TEXT, json_max_points=JSON_DEFAULT_MAX_POINTS)
def get_dataset_data(
    dataset_id: str,
    format: Literal["json", "csv", "ndjson", "hdf5"] = "json",
    max_points: int | None = Query(
        None, ge=2, description=f"json: at most this many points per column (default {JSON_DEFAULT_MAX_POINTS})"
    ),
    start: int = Query(0, ge=0, description="first sample (0-based)"),
    stop: int | None = Query(None, ge=1, description="end sample, exclusive (default: the last)"),
    store: Store = Depends(get_store),
) -> StreamingResponse:
    """The samples, streamed: memory does not grow with the dataset.

    - ``json`` (default): ``{{"id", "sample_rate_hz", "samples", "stride", "decimated",
      "full_resolution", "units", "t_s": [...], "u_y_v": [...], …}}``, every ``stride``-th sample so
      that a column has at most ``max_points`` points (default {json_max_points}).
      For every sample use ``format=csv`` or ``format=ndjson`` (named in ``full_resolution``).
    - ``csv``: header ``t,u_y,x_y,u_z,x_z`` (s, V, µm), every sample; importable as it is.
    - ``ndjson``: a first line ``{{"id", "sample_rate_hz", "units", "columns", "samples",
      "rows_per_line"}}``, then one line per chunk of rows, ``{{"start": <first row>, "t_s": [...], …}}``.
    - ``hdf5``: one dataset per array (``unit`` attribute), the metadata as attributes.

    ``start``/``stop`` cut every format to samples ``start:stop`` (``max_points`` then applies to
    the cut). The file is checked against its SHA-256 before the first byte is sent (500 if it
    does not match).
    """
    route = f"/api/datasets/{dataset_id}/data?format="
    chunks = export_chunks(
        store,
        dataset_id,
        format,
        start=start,
        stop=stop,
        max_points=max_points,
        full_resolution={"csv": route + "csv", "ndjson": route + "ndjson"},
    )
    suffix = "h5" if format == "hdf5" else format
    headers = {} if format == "json" else {"Content-Disposition": f'attachment; filename="{dataset_id}.{suffix}"'}
    return StreamingResponse(iterate_bulk(chunks), media_type=MEDIA_TYPES[format], headers=headers)
