"""Downloads: a stored dataset's samples as a stream of bytes in one format, cut to ``start:stop``.

Memory does not grow with the dataset: the arrays are opened lazily (after the file was checked
against its SHA-256) and written a chunk of rows at a time (service.science.data.export).
"""

from __future__ import annotations

from collections.abc import Iterator

from service.science.data.datasets import units_for
from service.science.data.export import (
    RowRange,
    csv_chunks,
    export_names,
    hdf5_chunks,
    json_chunks,
    json_stride,
    ndjson_chunks,
)
from service.science.errors import FieldError
from service.store import Store, StoredArrays

FORMATS = ("json", "csv", "ndjson", "hdf5")
#: the dataset's fields an HDF5 file carries as attributes
HDF5_ATTRIBUTES = (
    "id",
    "name",
    "source",
    "sample_rate_hz",
    "blocks",
    "plan",
    "config",
    "units",
    "software_version",
    "created_at",
    "partial",
    "sha256",
)


def export_chunks(
    store: Store,
    dataset_id: str,
    format: str,
    *,
    start: int = 0,
    stop: int | None = None,
    max_points: int | None = None,
    full_resolution: dict[str, str] | None = None,
) -> Iterator[bytes]:
    """The bytes of the download of samples ``start:stop`` (default: every one) in ``format``:
    ``json`` every stride-th sample, at most ``max_points`` per column (default
    JSON_DEFAULT_MAX_POINTS), with ``full_resolution`` (where to get every sample) in its header;
    ``csv``, ``ndjson``, ``hdf5`` every sample. FieldError names ``start`` when the cut is empty;
    IntegrityError if the file does not match its checksum. The arrays close when the stream ends."""
    row = store.get_dataset(dataset_id)
    stop = row["samples"] if stop is None else min(stop, row["samples"])
    if start >= stop:
        raise FieldError("start", f"no samples in {start}:{stop}; the dataset has {row['samples']} (0-based)")
    source = store.open_arrays(dataset_id)
    view = source if (start, stop) == (0, row["samples"]) else RowRange(source, start, stop)
    meta = {
        "id": dataset_id,
        "sample_rate_hz": row["sample_rate_hz"],
        "units": units_for(export_names(source)),
        **({} if view is source else {"start": start, "stop": stop}),
    }
    if format == "csv":
        chunks = csv_chunks(view)
    elif format == "ndjson":
        chunks = ndjson_chunks(view, meta)
    elif format == "hdf5":  # written to a temporary file on the first chunk, then sent
        chunks = hdf5_chunks(view, {**meta, **{k: row[k] for k in HDF5_ATTRIBUTES}})
    else:
        stride = json_stride(view.length, max_points)
        chunks = json_chunks(
            view,
            {
                **meta,
                "samples": row["samples"],
                "stride": stride,
                "decimated": stride > 1,
                "full_resolution": full_resolution or {},
            },
            stride,
        )
    return _closing(source, chunks)


def _closing(source: StoredArrays, chunks: Iterator[bytes]) -> Iterator[bytes]:
    """``chunks``, closing ``source`` when they end (or the client goes away)."""
    with source:
        yield from chunks
