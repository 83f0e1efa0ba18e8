"""Dataset downloads, encoded a chunk at a time: the dataset CSV, NDJSON, JSON, HDF5.

Every encoder is a sync generator over an array source (``StoredArrays`` from the store, or
``MemoryArrays`` around a dict): it reads a bounded number of rows, encodes them and yields bytes,
so memory does not grow with the dataset and no step holds the GIL for more than a few
milliseconds (Starlette iterates a sync generator in its threadpool). No HTTP and no store here.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Iterator
from typing import BinaryIO

import numpy as np

from service.science.data.datasets import UNITS, csv_name, ordered_names

#: values (rows × columns) per chunk sent: a few milliseconds of float formatting
CHUNK_VALUES = 8192
#: values per formatting call (~0.6 ms): one ``%`` holds the interpreter lock throughout (8192 held it
#: 2.5 ms), so a chunk is formatted in pieces and the emergency stop's thread waits at most one
FORMAT_VALUES = 2048
#: rows per HDF5 write and per HDF5 chunk, each compressed as it is written (no chunk cache, so
#: closing the file flushes nothing): ~2 ms of gzip per column and step
HDF5_CHUNK_ROWS = 8192
#: a JSON download without ``max_points`` is decimated to at most this many points per column
JSON_DEFAULT_MAX_POINTS = 10_000
#: CSV number format: 12 significant digits round-trip through an import far below 1e-9
CSV_NUMBER_FORMAT = "%.12g"
FILE_BLOCK_BYTES = 1 << 20
_COMPACT = {"separators": (",", ":")}


class MemoryArrays:
    """Equal-length 1-D arrays in a dict, read like ``StoredArrays`` (``names``, ``length``, ``rows``)."""

    def __init__(self, arrays: dict[str, np.ndarray]):
        self._arrays = {name: np.asarray(values) for name, values in arrays.items()}
        self.names = list(self._arrays)
        self.length = len(next(iter(self._arrays.values()))) if self._arrays else 0

    def rows(self, start: int, stop: int, step: int = 1, names: list[str] | None = None) -> dict[str, np.ndarray]:
        return {name: self._arrays[name][start:stop:step] for name in (names or self.names)}


class RowRange:
    """Rows ``start:stop`` of an array source, read like one (``names``, ``length``, ``rows``)."""

    def __init__(self, source, start: int, stop: int):
        self._source, self._start = source, start
        self.names = source.names
        self.length = max(0, min(stop, source.length) - start)

    def rows(self, start: int, stop: int, step: int = 1, names: list[str] | None = None) -> dict[str, np.ndarray]:
        stop = min(stop, self.length)
        return self._source.rows(self._start + start, self._start + stop, step, names)


def rows_per_chunk(n_columns: int) -> int:
    """Rows encoded per step for ``n_columns`` columns."""
    return max(256, CHUNK_VALUES // max(1, n_columns))


def export_names(source) -> list[str]:
    """The columns of a download: the dataset CSV's order, then any others (e.g. ``ref_y_um``)."""
    known = ordered_names(source.names)
    return known + [name for name in source.names if name not in known]


def csv_chunks(source) -> Iterator[bytes]:
    """The dataset CSV: header ``t,u_y,x_y,…`` (extra arrays under their own names), then one row
    per sample (``CSV_NUMBER_FORMAT``)."""
    names = export_names(source)
    yield (",".join(csv_name(name) for name in names) + "\n").encode()
    row_format = ",".join([CSV_NUMBER_FORMAT] * len(names)) + "\n"
    step = rows_per_chunk(len(names))
    for start in range(0, source.length, step):
        block = source.rows(start, start + step, names=names)
        table = np.column_stack([block[name].astype(float, copy=False) for name in names])
        rows = max(1, FORMAT_VALUES // len(names))
        yield "".join(
            (row_format * piece.shape[0]) % tuple(piece.ravel().tolist())
            for piece in (table[k : k + rows] for k in range(0, table.shape[0], rows))
        ).encode()


def to_csv(arrays: dict[str, np.ndarray]) -> str:
    """``csv_chunks`` of arrays in memory, as one string."""
    return b"".join(csv_chunks(MemoryArrays(arrays))).decode()


def ndjson_chunks(source, meta: dict) -> Iterator[bytes]:
    """NDJSON: a first line ``{**meta, "columns": [...], "samples", "rows_per_line"}``, then one line
    per chunk of rows, ``{"start": <index of its first row>, "<column>": [...], …}``."""
    names = export_names(source)
    step = rows_per_chunk(len(names))
    yield (json.dumps({**meta, "columns": names, "samples": source.length, "rows_per_line": step}) + "\n").encode()
    for start in range(0, source.length, step):
        block = source.rows(start, start + step, names=names)
        line = {"start": start, **{name: block[name].tolist() for name in names}}
        yield (json.dumps(line, **_COMPACT) + "\n").encode()


def json_chunks(source, meta: dict, stride: int) -> Iterator[bytes]:
    """One JSON object, ``{**meta, "<column>": [every stride-th sample], …}``, written a chunk at a time."""
    head = json.dumps(meta)
    yield head[:-1].encode()
    separator = ", " if meta else ""
    span = rows_per_chunk(len(source.names)) * stride
    for name in export_names(source):
        yield f"{separator}{json.dumps(name)}: [".encode()
        separator, comma = ", ", ""
        for start in range(0, source.length, span):
            values = source.rows(start, start + span, stride, names=[name])[name]
            if values.size:
                yield (comma + json.dumps(values.tolist(), **_COMPACT)[1:-1]).encode()
                comma = ","
        yield b"]"
    yield b"}"


def json_stride(samples: int, max_points: int | None) -> int:
    """Decimation of a JSON download: every stride-th sample, at most ``max_points`` (default
    JSON_DEFAULT_MAX_POINTS) per column."""
    limit = max_points or JSON_DEFAULT_MAX_POINTS
    return max(1, -(-samples // limit))


def hdf5_file(source, meta: dict) -> BinaryIO:
    """An HDF5 file in an anonymous temporary file (rewound; close it): one gzip dataset per array
    with a ``unit`` attribute, written HDF5_CHUNK_ROWS at a time, and ``meta`` as attributes
    (JSON text for nested fields, None left out)."""
    import h5py

    handle = tempfile.TemporaryFile()
    try:
        with h5py.File(handle, "w", rdcc_nbytes=0) as h5:
            names = export_names(source)
            for start in range(0, max(source.length, 1), HDF5_CHUNK_ROWS):
                for name, values in source.rows(start, start + HDF5_CHUNK_ROWS, names=names).items():
                    if name not in h5:
                        ds = h5.create_dataset(
                            name,
                            shape=(source.length,),
                            dtype=values.dtype,
                            compression="gzip",
                            chunks=(max(1, min(HDF5_CHUNK_ROWS, source.length)),),
                        )
                        ds.attrs["unit"] = UNITS.get(name, "")
                    h5[name][start : start + values.size] = values
            for key, value in meta.items():
                if value is not None:
                    h5.attrs[key] = value if isinstance(value, (int, float, str, bool)) else json.dumps(value)
        handle.seek(0)
        return handle
    except BaseException:
        handle.close()
        raise


def hdf5_chunks(source, meta: dict) -> Iterator[bytes]:
    """``hdf5_file``, written when the first chunk is asked for, then sent FILE_BLOCK_BYTES at a time."""
    yield from file_chunks(hdf5_file(source, meta))


def to_hdf5(arrays: dict[str, np.ndarray], meta: dict) -> bytes:
    """``hdf5_file`` of arrays in memory, as bytes."""
    with hdf5_file(MemoryArrays(arrays), meta) as handle:
        return handle.read()


def file_chunks(handle: BinaryIO) -> Iterator[bytes]:
    """The rest of an open file, FILE_BLOCK_BYTES at a time; closes it at the end."""
    with handle:
        yield from iter(lambda: handle.read(FILE_BLOCK_BYTES), b"")
