"""Dataset arrays: parse CSV/whitespace tables (with a column mapping) as a stream, and validate.

Arrays inside the service are named with units: ``t_s``, ``u_y_v``, ``x_y_um``, ``u_z_v``,
``x_z_um``, ``temp_c``. Files follow the dataset CSV format: a header row ``t,u_y,x_y,u_z,x_z[,temp_c]``
(``t`` in seconds, volts at the actuator, micrometres), or ``u,x`` plus an ``axis``. Headerless
or foreign files need ``columns``, a mapping such as ``{"u": 0, "x": 4}`` (0-based indices or
header names; a value may also be ``{"column": 4, "scale": 1.0, "offset": 0.0}`` or
``{"column": 4, "unit": "nm"}``), and ``sample_rate_hz`` when there is no time column. Columns the
mapping does not name are never read (an unnamed index column, notes, empty columns).

Units written in the header (``Time [ms]``, ``x_y_nm``, ``Position/mm``, or a units row under the
header; service.science.data.units) are converted to seconds, volts, micrometres and °C, and the
conversion is noted; a unit of the wrong quantity, or one this service does not know, is refused
naming the column, unless the mapping gives the column's ``scale`` (then that is the whole
conversion). Measured data is not a command: any drive range is accepted and recorded
(``drive_range_v``); values implausible for a piezo stage (a stroke of millimetres, a sample rate
under 100 Hz) are accepted with a note saying which unit may be meant. No HTTP and no store here.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np

from drivers.interfaces import AXES
from service.science.data.columns import CANONICAL, column_specs, csv_name, parse_mapping, scaled_columns
from service.science.data.table_reader import DataError, TableReader

__all__ = [
    "DataError",
    "ParsedTable",
    "parse_table",
    "check_sample_rate",
    "units_for",
    "ordered_names",
    "csv_name",
    "stored_sample_rate_hz",
    "SAMPLE_RATE_RANGE_HZ",
    "CANONICAL",
    "UNITS",
]

#: sample rates (Hz) an imported record may have, given or implied by its time column
SAMPLE_RATE_RANGE_HZ = (1.0, 10e6)
MIN_ROWS = 10
UNITS = {
    "t_s": "s",
    "temp_c": "°C",
    **{f"u_{a}_v": "V" for a in AXES},
    **{f"x_{a}_um": "µm" for a in AXES},
    **{f"ref_{a}_um": "µm" for a in AXES},
}


#: what a piezo stage plausibly does; beyond it an import is accepted with a note on the unit
PLAUSIBLE_STROKE_UM = 1000.0
PLAUSIBLE_DRIVE_V = 1000.0
PLAUSIBLE_MIN_SAMPLE_RATE_HZ = 100.0


@dataclass
class ParsedTable:
    """Arrays with unit names, the axes present, the sample rate (Hz), each axis's drive range (V),
    and ``notes``: the units converted and values a piezo stage would hardly show, in words."""

    arrays: dict[str, np.ndarray]
    axes: list[str]
    sample_rate_hz: float
    drive_range_v: dict[str, list[float]]
    notes: list[str] = field(default_factory=list)

    @property
    def samples(self) -> int:
        return len(self.arrays["t_s"])


def parse_table(
    source: bytes | BinaryIO,
    *,
    columns: dict | str | None = None,
    axis: str | None = None,
    sample_rate_hz: float | None = None,
    delimiter: str | None = None,
) -> ParsedTable:
    """Parse and validate an uploaded table (bytes, or a binary file object read as a stream).

    The options and the first line decide the layout and the column mapping, so a request that
    cannot succeed (no header and no mapping, a column that does not exist, no time column and no
    ``sample_rate_hz``, …) is refused before any data row is read. Every refusal is a DataError
    naming the field.
    """
    mapping = parse_mapping(columns)
    sample_rate_hz = check_sample_rate(sample_rate_hz)
    reader = TableReader(io.BytesIO(source) if isinstance(source, (bytes, bytearray)) else source, delimiter)
    specs, notes = column_specs(mapping, reader.layout, axis)
    if "t_s" not in specs and sample_rate_hz is None:
        raise DataError("sample_rate_hz", "the file has no time column t; give sample_rate_hz")
    raw, rows = reader.columns([spec.index for spec in specs.values()])
    if rows < MIN_ROWS:
        raise DataError("file", f"has {rows} data rows; at least {MIN_ROWS} are needed")
    arrays = scaled_columns(raw, specs)
    for name, data in arrays.items():
        if not np.isfinite(data).all():
            bad = np.flatnonzero(~np.isfinite(data))
            raise DataError(
                csv_name(name), f"row {int(bad[0]) + 1} of the data is NaN or infinite ({bad.size} such values)"
            )
    axes = [a for a in AXES if f"u_{a}_v" in arrays]
    drive_range_v = {a: [float(arrays[f"u_{a}_v"].min()), float(arrays[f"u_{a}_v"].max())] for a in axes}
    rate = _sample_rate(arrays.pop("t_s", None), sample_rate_hz)
    arrays = {"t_s": np.arange(rows) / rate, **arrays}
    notes = _read_as(reader) + notes + _implausible(arrays, rate, "t_s" in specs and specs["t_s"].unit is None)
    return ParsedTable(arrays=arrays, axes=axes, sample_rate_hz=rate, drive_range_v=drive_range_v, notes=notes)


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
        raise DataError(
            field,
            f"{value:g} Hz is outside {low:g} Hz–{high / 1e6:g} MHz"
            if math.isfinite(value)
            else f"must be a finite number of hertz in {low:g} Hz–{high / 1e6:g} MHz",
        )
    return value


def stored_sample_rate_hz(row: dict, field: str = "datasets") -> float:
    """A stored dataset's sample rate (Hz); a DataError naming ``field`` if it lies outside
    SAMPLE_RATE_RANGE_HZ (a record stored before the bounds existed cannot be modelled)."""
    try:
        return check_sample_rate(row["sample_rate_hz"])
    except DataError as exc:
        raise DataError(
            field, f"dataset {row['id']}: sample_rate_hz {exc.message}; import it again with a sample rate in range"
        ) from None


def units_for(arrays) -> dict[str, str]:
    """Units of the arrays named (a dict of arrays or a list of names)."""
    return {name: UNITS[name] for name in arrays if name in UNITS}


def ordered_names(names) -> list[str]:
    """Array names in file order (``t_s``, per axis ``u_<a>_v``, ``x_<a>_um``, ``temp_c``)."""
    order = ["t_s"] + [n for a in AXES for n in (f"u_{a}_v", f"x_{a}_um")] + ["temp_c"]
    return [n for n in order if n in names]


def _sample_rate(t: np.ndarray | None, sample_rate_hz: float | None) -> float:
    """The given rate (Hz), else the one the time column implies (the slope of a straight line
    through the stamps: a jittered or rounded clock's steps average out); both are checked to agree,
    and an implied rate must lie in SAMPLE_RATE_RANGE_HZ."""
    if t is None:
        return float(sample_rate_hz)
    dt = np.diff(t)
    if dt.min() <= 0:
        raise DataError("t", f"time must increase; row {int(np.argmax(dt <= 0)) + 2} does not")
    index = np.arange(t.size) - 0.5 * (t.size - 1)
    mean = float(index @ (t - t.mean()) / (index @ index))  # least-squares step (s)
    if max(float(dt.max()) - mean, mean - float(dt.min())) > 0.01 * mean and not _rounded_grid(t, mean):
        raise DataError(
            "t",
            "the samples are not evenly spaced (spacing varies by more than 1 %); if the time "
            "stamps are jittered but the samples were clocked evenly, leave t out of the "
            "columns and give sample_rate_hz",
        )
    rate = float(f"{1.0 / mean:.10g}")  # drop float noise of the time column
    if sample_rate_hz is not None and abs(rate - sample_rate_hz) > 0.01 * sample_rate_hz:
        raise DataError("sample_rate_hz", f"{sample_rate_hz:g} Hz disagrees with the time column ({rate:.6g} Hz)")
    if sample_rate_hz is None:
        check_sample_rate(rate, field="t")
    return float(sample_rate_hz if sample_rate_hz is not None else rate)


def _rounded_grid(t: np.ndarray, step_s: float) -> bool:
    """Whether ``t`` is an even grid of ``step_s`` written with too few decimals (3 kHz as 0.0003,
    0.0007, 0.0010 s): every stamp a multiple of 10⁻ᵏ s, none further than half of that from the grid."""
    grid = t.mean() + step_s * (np.arange(t.size) - 0.5 * (t.size - 1))
    for k in range(10):
        quantum = 10.0**-k
        scaled = t / quantum
        if np.max(np.abs(scaled - np.round(scaled))) <= 1e-6 * max(1.0, float(np.max(np.abs(scaled))) * 1e-9):
            return bool(np.max(np.abs(t - grid)) <= 0.5 * quantum * (1 + 1e-6) + abs(step_s) * 1e-9)
    return False


def _read_as(reader: TableReader) -> list[str]:
    """Notes on how the file was read where it differs from this service's CSV: its encoding, decimal
    commas, a units row under the header."""
    layout, notes = reader.layout, []
    if reader.encoding != "utf-8":
        notes.append(f"file: read as {reader.encoding.upper()} text")
    if layout.decimal_comma:
        notes.append(
            f"file: numbers written with decimal commas, read as decimal points "
            f"(fields separated by {'semicolons' if layout.sep == ';' else 'whitespace'})"
        )
    if layout.units is not None:
        notes.append(f"file: a units row under the header ({', '.join(layout.units)}) gives the columns' units")
    return notes


def _implausible(arrays: dict[str, np.ndarray], rate_hz: float, time_without_unit: bool) -> list[str]:
    """Notes on values a piezo stage would hardly show, with the unit that may be meant."""
    notes = []
    for name, data in arrays.items():
        span = float(np.ptp(data)) if data.size else 0.0
        if name.startswith("x_") and span > PLAUSIBLE_STROKE_UM:
            notes.append(
                f"{csv_name(name)} spans {span:.4g} µm, more than a piezo stage moves; if its values "
                f"are nanometres, name the column {csv_name(name)}_nm or '{csv_name(name)} [nm]'"
            )
        if name.startswith("u_") and span > PLAUSIBLE_DRIVE_V:
            notes.append(
                f"{csv_name(name)} spans {span:.4g} V; if its values are millivolts, name the column "
                f"{csv_name(name)}_mv or '{csv_name(name)} [mV]'"
            )
    if time_without_unit and rate_hz < PLAUSIBLE_MIN_SAMPLE_RATE_HZ:
        notes.append(
            f"t implies {rate_hz:.4g} samples per second; if its values are milliseconds, name the "
            "column t_ms or 't [ms]'"
        )
    return notes
