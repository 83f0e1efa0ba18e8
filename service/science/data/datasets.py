"""Dataset arrays: parse CSV/whitespace tables (with a column mapping) as a stream, and validate.

Arrays inside the service are named with units: ``t_s``, ``u_y_v``, ``x_y_um``, ``u_z_v``,
``x_z_um``, ``temp_c``. Files follow DESIGN.md §4: a header row ``t,u_y,x_y,u_z,x_z[,temp_c]``
(``t`` in seconds, volts at the actuator, micrometres), or ``u,x`` plus an ``axis``. Headerless
or foreign files need ``columns``, a mapping such as ``{"u": 0, "x": 4}`` (0-based indices or
header names; a value may also be ``{"column": 4, "scale": 1.0, "offset": 0.0}``), and
``sample_rate_hz`` when there is no time column. Columns the mapping does not name are never
read (an unnamed index column, notes, empty columns). Measured data is not a command: any drive
range is accepted and recorded (``drive_range_v``). No HTTP and no store here.
"""
from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass
from typing import BinaryIO

import numpy as np

from drivers.interfaces import AXES
from service.science.data.table_reader import DataError, Layout, TableReader

__all__ = ["DataError", "ParsedTable", "parse_table", "check_sample_rate", "units_for", "ordered_names",
           "csv_name", "stored_sample_rate_hz", "SAMPLE_RATE_RANGE_HZ", "CANONICAL", "UNITS"]

#: sample rates (Hz) an imported record may have, given or implied by its time column
SAMPLE_RATE_RANGE_HZ = (1.0, 10e6)
MIN_ROWS = 10
# canonical column name -> internal array name
CANONICAL = {"t": "t_s", "temp_c": "temp_c", "u": "u", "x": "x",
             **{f"u_{a}": f"u_{a}_v" for a in AXES}, **{f"x_{a}": f"x_{a}_um" for a in AXES}}
# header spellings accepted for each canonical name (our own export and the internal names)
ALIASES = {"t_s": "t", "time": "t", "time_s": "t", **{f"u_{a}_v": f"u_{a}" for a in AXES},
           **{f"x_{a}_um": f"x_{a}" for a in AXES}, "u_v": "u", "x_um": "x"}
UNITS = {"t_s": "s", "temp_c": "°C", **{f"u_{a}_v": "V" for a in AXES}, **{f"x_{a}_um": "µm" for a in AXES},
         **{f"ref_{a}_um": "µm" for a in AXES}}


@dataclass
class ParsedTable:
    """Arrays with unit names, the axes present, the sample rate (Hz) and each axis's drive range (V)."""

    arrays: dict[str, np.ndarray]
    axes: list[str]
    sample_rate_hz: float
    drive_range_v: dict[str, list[float]]

    @property
    def samples(self) -> int:
        return len(self.arrays["t_s"])


def parse_table(source: bytes | BinaryIO, *, columns: dict | str | None = None, axis: str | None = None,
                sample_rate_hz: float | None = None, delimiter: str | None = None) -> ParsedTable:
    """Parse and validate an uploaded table (bytes, or a binary file object read as a stream).

    The options and the first line decide the layout and the column mapping, so a request that
    cannot succeed (no header and no mapping, a column that does not exist, no time column and no
    ``sample_rate_hz``, …) is refused before any data row is read. Every refusal is a DataError
    naming the field.
    """
    mapping = _parse_mapping(columns)
    sample_rate_hz = check_sample_rate(sample_rate_hz)
    reader = TableReader(io.BytesIO(source) if isinstance(source, (bytes, bytearray)) else source, delimiter)
    specs = _column_specs(mapping, reader.layout, axis)
    if "t_s" not in specs and sample_rate_hz is None:
        raise DataError("sample_rate_hz", "the file has no time column t; give sample_rate_hz")
    raw, rows = reader.columns([index for index, _, _ in specs.values()])
    if rows < MIN_ROWS:
        raise DataError("file", f"has {rows} data rows; at least {MIN_ROWS} are needed")
    arrays = _scaled(raw, specs)
    for name, data in arrays.items():
        if not np.isfinite(data).all():
            bad = np.flatnonzero(~np.isfinite(data))
            raise DataError(csv_name(name), f"row {int(bad[0]) + 1} of the data is NaN or infinite "
                                            f"({bad.size} such values)")
    axes = [a for a in AXES if f"u_{a}_v" in arrays]
    drive_range_v = {a: [float(arrays[f"u_{a}_v"].min()), float(arrays[f"u_{a}_v"].max())] for a in axes}
    rate = _sample_rate(arrays.pop("t_s", None), sample_rate_hz)
    arrays = {"t_s": np.arange(rows) / rate, **arrays}
    return ParsedTable(arrays=arrays, axes=axes, sample_rate_hz=rate, drive_range_v=drive_range_v)


def check_sample_rate(sample_rate_hz: float | None, field: str = "sample_rate_hz") -> float | None:
    """``sample_rate_hz`` as a float if it lies in SAMPLE_RATE_RANGE_HZ (None stays None); else a
    DataError naming ``field``."""
    if sample_rate_hz is None:
        return None
    low, high = SAMPLE_RATE_RANGE_HZ
    try:
        value = float(sample_rate_hz)
    except (TypeError, ValueError):
        raise DataError(field, f"must be a number of hertz, got {sample_rate_hz!r}") from None
    if not (math.isfinite(value) and low <= value <= high):
        raise DataError(field, f"{value:g} Hz is outside {low:g} Hz–{high / 1e6:g} MHz" if math.isfinite(value)
                        else f"must be a finite number of hertz in {low:g} Hz–{high / 1e6:g} MHz")
    return value


def stored_sample_rate_hz(row: dict, field: str = "datasets") -> float:
    """A stored dataset's sample rate (Hz); a DataError naming ``field`` if it lies outside
    SAMPLE_RATE_RANGE_HZ (a record stored before the bounds existed cannot be modelled)."""
    try:
        return check_sample_rate(row["sample_rate_hz"])
    except DataError as exc:
        raise DataError(field, f"dataset {row['id']}: sample_rate_hz {exc.message}; import it again with a "
                               "sample rate in range") from None


def units_for(arrays) -> dict[str, str]:
    """Units of the arrays named (a dict of arrays or a list of names)."""
    return {name: UNITS[name] for name in arrays if name in UNITS}


def ordered_names(names) -> list[str]:
    """Array names in file order (``t_s``, per axis ``u_<a>_v``, ``x_<a>_um``, ``temp_c``)."""
    order = ["t_s"] + [n for a in AXES for n in (f"u_{a}_v", f"x_{a}_um")] + ["temp_c"]
    return [n for n in order if n in names]


def csv_name(name: str) -> str:
    """The DESIGN §4 column name of an internal array name (``u_y_v`` → ``u_y``)."""
    inverse = {v: k for k, v in CANONICAL.items()}
    return inverse.get(name, name)


# ---------------------------------------------------------------------- helpers
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


def _column_specs(mapping: dict | None, layout: Layout, axis: str | None) -> dict[str, tuple[int, float, float]]:
    """Internal array name → (0-based column, scale, offset), from the mapping or the header row."""
    header = layout.header
    if mapping is None:
        if header is None:
            raise DataError("columns", 'the file has no header row; give a column mapping such as '
                                       '{"u": 0, "x": 4} (0-based column indices)')
        mapping = {ALIASES.get(name, name): name for name in header if ALIASES.get(name, name) in CANONICAL}
        if not mapping:
            raise DataError("file", f"no known columns in header {layout.written}; expected t, u_y, x_y, u_z, "
                                    "x_z, temp_c or u, x")
    specs = {}
    for name, spec in mapping.items():
        canonical = ALIASES.get(name, name)
        if canonical not in CANONICAL:
            raise DataError("columns", f"unknown column name {name!r}; use t, u_y, x_y, u_z, x_z, "
                                       "temp_c, or u and x with an axis")
        specs[canonical] = _column_spec(name, spec, layout)
    return _name_axes(specs, axis)


def _scaled(raw: dict[int, np.ndarray], specs: dict[str, tuple[int, float, float]]) -> dict[str, np.ndarray]:
    """The named arrays: each mapped column times its scale plus its offset (in place when the
    column is named once)."""
    uses = [index for index, _, _ in specs.values()]
    arrays = {}
    for name, (index, scale, offset) in specs.items():
        values = raw[index] if uses.count(index) == 1 else raw[index].copy()
        if scale != 1.0:
            values *= scale
        if offset != 0.0:
            values += offset
        arrays[name] = values
    return arrays


def _column_spec(name: str, spec, layout: Layout) -> tuple[int, float, float]:
    header, width = layout.header, layout.width
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
            raise DataError("columns", f"{name}: no column named {spec!r} in the header {layout.written}")
        return header.index(spec.lower()), scale, offset
    if not 0 <= spec < width:
        raise DataError("columns", f"{name}: column {spec} does not exist; the file has {width} columns "
                                   f"(0-based: 0..{width - 1})")
    return spec, scale, offset


def _name_axes(values: dict, axis: str | None) -> dict:
    """Canonical columns → internal names; ``u``/``x`` become the given axis."""
    arrays: dict = {}
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


def _sample_rate(t: np.ndarray | None, sample_rate_hz: float | None) -> float:
    """The given rate (Hz), else the one the time column implies; both are checked to agree, and an
    implied rate must lie in SAMPLE_RATE_RANGE_HZ."""
    if t is None:
        return float(sample_rate_hz)
    dt = np.diff(t)
    if dt.min() <= 0:
        raise DataError("t", f"time must increase; row {int(np.argmax(dt <= 0)) + 2} does not")
    median = float(np.median(dt))
    if max(float(dt.max()) - median, median - float(dt.min())) > 0.01 * median:
        raise DataError("t", "the samples are not evenly spaced (spacing varies by more than 1 %)")
    rate = float(f"{1.0 / median:.10g}")  # drop float noise of the time column
    if sample_rate_hz is not None and abs(rate - sample_rate_hz) > 0.01 * sample_rate_hz:
        raise DataError("sample_rate_hz", f"{sample_rate_hz:g} Hz disagrees with the time column "
                                          f"({rate:.6g} Hz)")
    if sample_rate_hz is None:
        check_sample_rate(rate, field="t")
    return float(sample_rate_hz if sample_rate_hz is not None else rate)
