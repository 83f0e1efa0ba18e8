"""Dataset arrays: parse CSV/whitespace tables (with a column mapping), validate, export CSV/HDF5.

Arrays inside the service are named with units: ``t_s``, ``u_y_v``, ``x_y_um``, ``u_z_v``,
``x_z_um``, ``temp_c``. Files follow DESIGN.md §4: a header row ``t,u_y,x_y,u_z,x_z[,temp_c]``
(``t`` in seconds, volts at the actuator, micrometres), or ``u,x`` plus an ``axis``. Headerless
or foreign files need ``columns``, a mapping such as ``{"u": 0, "x": 4}`` (0-based indices or
header names; a value may also be ``{"column": 4, "scale": 1.0, "offset": 0.0}``), and
``sample_rate_hz`` when there is no time column. No HTTP and no store here.
"""
from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass

import numpy as np

from drivers.interfaces import AXES
from service.errors import FieldError

ACTUATOR_RANGE_V = (0.0, 120.0)
MIN_ROWS = 10
DELIMITERS = {"comma": ",", ",": ",", "tab": "\t", "\\t": "\t", "\t": "\t", "semicolon": ";", ";": ";",
              "whitespace": None, "space": None}
# canonical column name -> internal array name
CANONICAL = {"t": "t_s", "temp_c": "temp_c", "u": "u", "x": "x",
             **{f"u_{a}": f"u_{a}_v" for a in AXES}, **{f"x_{a}": f"x_{a}_um" for a in AXES}}
# header spellings accepted for each canonical name (our own export and the internal names)
ALIASES = {"t_s": "t", "time": "t", "time_s": "t", **{f"u_{a}_v": f"u_{a}" for a in AXES},
           **{f"x_{a}_um": f"x_{a}" for a in AXES}, "u_v": "u", "x_um": "x"}
UNITS = {"t_s": "s", "temp_c": "°C", **{f"u_{a}_v": "V" for a in AXES}, **{f"x_{a}_um": "µm" for a in AXES},
         **{f"ref_{a}_um": "µm" for a in AXES}}


class DataError(FieldError):
    """An uploaded table is malformed or out of range; ``field`` names the field or column."""


@dataclass
class ParsedTable:
    """Arrays with unit names, the axes present and the sample rate (hertz)."""

    arrays: dict[str, np.ndarray]
    axes: list[str]
    sample_rate_hz: float

    @property
    def samples(self) -> int:
        return len(self.arrays["t_s"])


def parse_table(content: bytes, *, columns: dict | str | None = None, axis: str | None = None,
                sample_rate_hz: float | None = None, delimiter: str | None = None) -> ParsedTable:
    """Parse and validate an uploaded table. Every refusal is a DataError naming the field."""
    mapping = _parse_mapping(columns)
    header, rows = _split_rows(content, delimiter)
    width = rows.shape[1]
    if mapping is None:
        if header is None:
            raise DataError("columns", 'the file has no header row; give a column mapping such as '
                                       '{"u": 0, "x": 4} (0-based column indices)')
        mapping = {ALIASES.get(name, name): name for name in header if ALIASES.get(name, name) in CANONICAL}
        if not mapping:
            raise DataError("file", f"no known columns in header {header}; expected t, u_y, x_y, u_z, "
                                    "x_z, temp_c or u, x")
    values: dict[str, np.ndarray] = {}
    for name, spec in mapping.items():
        canonical = ALIASES.get(name, name)
        if canonical not in CANONICAL:
            raise DataError("columns", f"unknown column name {name!r}; use t, u_y, x_y, u_z, x_z, "
                                       "temp_c, or u and x with an axis")
        index, scale, offset = _column_spec(name, spec, header, width)
        values[canonical] = rows[:, index] * scale + offset
    arrays = _name_axes(values, axis)
    for name, data in arrays.items():
        bad = np.flatnonzero(~np.isfinite(data))
        if bad.size:
            raise DataError(_csv_name(name), f"row {int(bad[0]) + 1} of the data is NaN or infinite "
                                             f"({bad.size} such values)")
    axes = [a for a in AXES if f"u_{a}_v" in arrays]
    for a in axes:
        u = arrays[f"u_{a}_v"]
        if u.min() < ACTUATOR_RANGE_V[0] or u.max() > ACTUATOR_RANGE_V[1]:
            raise DataError(f"u_{a}", f"spans {u.min():.4g}–{u.max():.4g} V; actuator volts must lie in "
                                      f"{ACTUATOR_RANGE_V[0]:g}–{ACTUATOR_RANGE_V[1]:g} V")
    rate = _sample_rate(arrays.pop("t_s", None), sample_rate_hz, len(rows))
    arrays = {"t_s": np.arange(len(rows)) / rate, **arrays}
    return ParsedTable(arrays=arrays, axes=axes, sample_rate_hz=rate)


def to_csv(arrays: dict[str, np.ndarray]) -> str:
    """The DESIGN.md §4 CSV: header ``t,u_y,x_y,…`` then one row per sample (%.9g)."""
    names = [name for name in _ordered(arrays)]
    table = np.column_stack([np.asarray(arrays[name], dtype=float) for name in names])
    buffer = io.StringIO()
    buffer.write(",".join(_csv_name(name) for name in names) + "\n")
    np.savetxt(buffer, table, delimiter=",", fmt="%.9g")
    return buffer.getvalue()


def to_hdf5(arrays: dict[str, np.ndarray], meta: dict) -> bytes:
    """An HDF5 file: one dataset per array (with a ``unit`` attribute) and the metadata as
    attributes (JSON text for nested fields)."""
    import h5py

    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as handle:
        for name in _ordered(arrays):
            ds = handle.create_dataset(name, data=np.asarray(arrays[name]), compression="gzip")
            ds.attrs["unit"] = UNITS.get(name, "")
        for key, value in meta.items():
            if value is None:
                continue
            handle.attrs[key] = value if isinstance(value, (int, float, str, bool)) else json.dumps(value)
    return buffer.getvalue()


def units_for(arrays: dict[str, np.ndarray]) -> dict[str, str]:
    return {name: UNITS[name] for name in arrays if name in UNITS}


# ---------------------------------------------------------------------- helpers
def _ordered(arrays: dict) -> list[str]:
    order = ["t_s"] + [n for a in AXES for n in (f"u_{a}_v", f"x_{a}_um")] + ["temp_c"]
    return [n for n in order if n in arrays]


def _csv_name(name: str) -> str:
    inverse = {v: k for k, v in CANONICAL.items()}
    return inverse.get(name, name)


def _parse_mapping(columns: dict | str | None) -> dict | None:
    if columns in (None, "", {}):
        return None
    if isinstance(columns, str):
        try:
            columns = json.loads(columns)
        except json.JSONDecodeError as exc:
            raise DataError("columns", f"is not valid JSON ({exc.msg} at character {exc.pos})") from None
    if not isinstance(columns, dict) or not columns:
        raise DataError("columns", 'must be a JSON object such as {"u": 0, "x": 4}')
    return columns


def _split_rows(content: bytes, delimiter: str | None) -> tuple[list[str] | None, np.ndarray]:
    try:
        text = content.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise DataError("file", "is not UTF-8 text") from None
    lines = [(k + 1, line.strip()) for k, line in enumerate(text.splitlines())]
    lines = [(k, line) for k, line in lines if line and not line.startswith("#")]
    if not lines:
        raise DataError("file", "is empty")
    if delimiter not in (None, "", "auto") and delimiter not in DELIMITERS:
        raise DataError("delimiter", f"unknown delimiter {delimiter!r}; use comma, tab, semicolon or whitespace")
    sep = DELIMITERS.get(delimiter) if delimiter not in (None, "", "auto") else ("," if "," in lines[0][1] else None)
    split = (lambda s: s.split()) if sep is None else (lambda s: [f.strip() for f in s.split(sep)])
    first = split(lines[0][1])
    header = None
    if not all(_is_number(f) for f in first):
        header = [f.strip().strip('"').lower() for f in first]
        lines = lines[1:]
    if len(lines) < MIN_ROWS:
        raise DataError("file", f"has {len(lines)} data rows; at least {MIN_ROWS} are needed")
    width = len(header) if header else len(first)
    rows = np.empty((len(lines), width))
    for r, (line_no, line) in enumerate(lines):
        fields = split(line)
        if len(fields) != width:
            raise DataError("file", f"line {line_no} has {len(fields)} fields; expected {width}")
        try:
            rows[r] = [float(f) for f in fields]
        except ValueError:
            bad = next(f for f in fields if not _is_number(f))
            raise DataError("file", f"line {line_no}: {bad!r} is not a number") from None
    return header, rows


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def _column_spec(name: str, spec, header: list[str] | None, width: int) -> tuple[int, float, float]:
    scale, offset = 1.0, 0.0
    if isinstance(spec, dict):
        if "column" not in spec:
            raise DataError("columns", f"{name}: a mapping object needs a 'column' key")
        try:
            scale, offset = float(spec.get("scale", 1.0)), float(spec.get("offset", 0.0))
        except (TypeError, ValueError):
            raise DataError("columns", f"{name}: scale and offset must be numbers") from None
        if not (math.isfinite(scale) and math.isfinite(offset)):
            raise DataError("columns", f"{name}: scale and offset must be finite")
        spec = spec["column"]
    if isinstance(spec, bool) or not isinstance(spec, (int, str)):
        raise DataError("columns", f"{name}: give a 0-based column index or a header name, not {spec!r}")
    if isinstance(spec, str):
        if header is None or spec.lower() not in header:
            raise DataError("columns", f"{name}: no column named {spec!r} in the header {header}")
        return header.index(spec.lower()), scale, offset
    if not 0 <= spec < width:
        raise DataError("columns", f"{name}: column {spec} does not exist; the file has {width} columns "
                                   f"(0-based: 0..{width - 1})")
    return spec, scale, offset


def _name_axes(values: dict[str, np.ndarray], axis: str | None) -> dict[str, np.ndarray]:
    """Canonical columns → internal names; ``u``/``x`` become the given axis."""
    arrays: dict[str, np.ndarray] = {}
    if "u" in values or "x" in values:
        if axis not in AXES:
            raise DataError("axis", f"a single-axis file (columns u, x) needs axis set to one of "
                                    f"{', '.join(AXES)}; got {axis!r}")
        if f"u_{axis}" in values or f"x_{axis}" in values:
            raise DataError("columns", f"both u/x and u_{axis}/x_{axis} are given")
        values = {({"u": f"u_{axis}", "x": f"x_{axis}"}.get(k, k)): v for k, v in values.items()}
    for key, data in values.items():
        arrays[CANONICAL[key]] = data
    axes = [a for a in AXES if f"u_{a}_v" in arrays or f"x_{a}_um" in arrays]
    if not axes:
        raise DataError("columns", "no axis data: give u and x (with axis) or u_y/x_y or u_z/x_z")
    for a in axes:
        for prefix, unit in (("u", "v"), ("x", "um")):
            if f"{prefix}_{a}_{unit}" not in arrays:
                raise DataError("columns", f"axis {a} needs both u_{a} and x_{a}; {prefix}_{a} is missing")
    return arrays


def _sample_rate(t: np.ndarray | None, sample_rate_hz: float | None, rows: int) -> float:
    if sample_rate_hz is not None and not (math.isfinite(sample_rate_hz) and sample_rate_hz > 0):
        raise DataError("sample_rate_hz", "must be a positive number of hertz")
    if t is None:
        if sample_rate_hz is None:
            raise DataError("sample_rate_hz", "the file has no time column t; give sample_rate_hz")
        return float(sample_rate_hz)
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise DataError("t", f"time must increase; row {int(np.flatnonzero(dt <= 0)[0]) + 2} does not")
    median = float(np.median(dt))
    if np.max(np.abs(dt - median)) > 0.01 * median:
        raise DataError("t", "the samples are not evenly spaced (spacing varies by more than 1 %)")
    rate = float(f"{1.0 / median:.10g}")  # drop float noise of the time column
    if sample_rate_hz is not None and abs(rate - sample_rate_hz) > 0.01 * sample_rate_hz:
        raise DataError("sample_rate_hz", f"{sample_rate_hz:g} Hz disagrees with the time column "
                                          f"({rate:.6g} Hz)")
    return float(sample_rate_hz if sample_rate_hz is not None else rate)
