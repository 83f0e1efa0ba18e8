"""The columns of an imported table: the mapping a request gives, or the header's own words (read
unasked where each column's unit confirms its quantity), each column's unit and conversion to this
service's (s, V, µm, °C), and the canonical names per axis. No HTTP and no store here."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

from drivers.interfaces import AXES
from service.science.data.table_reader import DataError, Layout
from service.science.data.units import SERVICE_UNIT, conversion, known_units, quantity_of_unit, split_unit

# canonical column name -> internal array name
CANONICAL = {
    "t": "t_s",
    "temp_c": "temp_c",
    "u": "u",
    "x": "x",
    **{f"u_{a}": f"u_{a}_v" for a in AXES},
    **{f"x_{a}": f"x_{a}_um" for a in AXES},
}
# header spellings accepted for each canonical name (our own export and the internal names)
ALIASES = {
    "t_s": "t",
    "time": "t",
    "time_s": "t",
    **{f"u_{a}_v": f"u_{a}" for a in AXES},
    **{f"x_{a}_um": f"x_{a}" for a in AXES},
    "u_v": "u",
    "x_um": "x",
}


def csv_name(name: str) -> str:
    """The dataset CSV's column name of an internal array name (``u_y_v`` → ``u_y``)."""
    inverse = {v: k for k, v in CANONICAL.items()}
    return inverse.get(name, name)


def parse_mapping(columns: dict | str | None) -> dict | None:
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


@dataclass(frozen=True)
class ColumnSpec:
    """Where a canonical column is read (0-based ``index``) and how: value·``scale`` + ``offset``
    in the service's unit; ``unit`` as the file gave it (None: the service's own)."""

    index: int
    scale: float = 1.0
    offset: float = 0.0
    unit: str | None = None


#: the quantity of each canonical column
QUANTITY = {
    "t": "time",
    "temp_c": "temperature",
    "u": "voltage",
    "x": "length",
    **{f"u_{a}": "voltage" for a in AXES},
    **{f"x_{a}": "length" for a in AXES},
}


def column_specs(mapping: dict | None, layout: Layout, axis: str | None) -> tuple[dict[str, ColumnSpec], list[str]]:
    """(internal array name → ColumnSpec, notes on the units converted), from the mapping or the
    header row (and its units)."""
    header, given = layout.header, mapping is not None
    if mapping is None:
        if header is None:
            raise DataError(
                "columns",
                'the file has no header row; give a column mapping such as {"u": 0, "x": 4} (0-based column indices)',
            )
        mapping = {}
        for index, written in enumerate(layout.written):
            canonical = _canonical(written)
            if canonical is not None and canonical not in mapping:
                mapping[canonical] = index
        read_by_words = None
        if not any(QUANTITY[name] in ("voltage", "length") for name in mapping):
            read_by_words = _unit_confirmed_mapping(layout.written)
            if read_by_words is None:
                raise DataError(
                    "file",
                    f"no known columns in header {layout.written}; expected t, u_y, x_y, u_z, "
                    "x_z, temp_c or u, x (a unit may follow: t_ms, 'x_y [nm]')" + _suggested_mapping(layout.written),
                )
            mapping.update({key: layout.written.index(written) for key, written in read_by_words.items()})
    specs, notes = {}, []
    if not given and read_by_words is not None:
        notes.append(
            "columns: read by their words, each confirmed by its unit: "
            + ", ".join(f"{written!r} as {key}" for key, written in read_by_words.items())
        )
    for name, spec in mapping.items():
        canonical = ALIASES.get(name, name)
        if canonical not in CANONICAL:
            raise DataError(
                "columns", f"unknown column name {name!r}; use t, u_y, x_y, u_z, x_z, temp_c, or u and x with an axis"
            )
        field = "columns" if given else csv_name(CANONICAL[canonical])
        specs[canonical] = _column_spec(canonical, name, spec, layout, notes, field)
    return _name_axes(specs, axis), notes


#: words other labs name their columns with: read unasked where each column's unit confirms its quantity
#: (``_unit_confirmed_mapping``), else the mapping a refusal suggests
COLUMN_WORDS = {
    "t": ("t", "time", "zeit", "temps", "tiempo"),
    "u": ("u", "v", "voltage", "drive", "input", "command", "spannung", "vin", "ua"),
    "x": ("x", "displacement", "position", "pos", "disp", "gauge", "sensor", "weg", "output", "d"),
}


def _suggested_mapping(written: list[str]) -> str:
    """'; if …, give columns {…} and axis' when the header's words name one time, drive and
    displacement column each (e.g. 'Time [ms]', 'Voltage (V)', 'Displacement [nm]'), else ''."""
    found = _words_of(written)
    if "u" not in found or "x" not in found:
        return ""
    return (
        f"; if {', '.join(repr(found[k]) + ' is ' + k for k in found)}, give columns "
        f"{json.dumps(found, ensure_ascii=False)} and the axis (units in the names are converted)"
    )


#: the quantity a column of COLUMN_WORDS must carry a unit of, for its words to be read unasked
WORD_QUANTITY = {"t": "time", "u": "voltage", "x": "length"}


def _words_of(written: list[str]) -> dict[str, str]:
    """key (t, u, x) → the one header name whose words name it (COLUMN_WORDS), where exactly one does."""
    found = {}
    for key, words in COLUMN_WORDS.items():
        hits = [w for w in written if split_unit(w)[0] in words]
        if len(hits) == 1:
            found[key] = hits[0]
    return found


def _unit_confirmed_mapping(written: list[str]) -> dict[str, str] | None:
    """The header names to read as u and x (and t) unasked, or None: each named by its words
    (``_words_of``) and carrying a unit of its quantity (``drive_V``, ``Displacement [nm]``,
    ``time_s``), so that the unit confirms what the words say. An ``Output (V)`` is a voltage, not the
    displacement its word may mean: refused, with the mapping suggested."""
    confirmed = {}
    for key, name in _words_of(written).items():
        unit = split_unit(name)[1]
        if unit is not None and quantity_of_unit(unit) == WORD_QUANTITY[key]:
            confirmed[key] = name
    return confirmed if "u" in confirmed and "x" in confirmed else None


def _canonical(written: str) -> str | None:
    """The canonical column a header name stands for (``Time [ms]`` → t, ``x_y_nm`` → x_y), or None."""
    whole = written.strip().strip('"').lower()
    if ALIASES.get(whole, whole) in CANONICAL:
        return ALIASES.get(whole, whole)
    name, unit = split_unit(written)
    canonical = ALIASES.get(name, name)
    return canonical if unit is not None and canonical in CANONICAL else None


def _written_unit(index: int, layout: Layout) -> tuple[str | None, str]:
    """(the unit the file gives column ``index``, where it says so): the header's own (``[ms]``,
    ``_nm``: only where the whole name is not one of the service's, such as ``u_y_v``), else the
    units row's."""
    if layout.written is not None:
        written = layout.written[index]
        whole = written.strip().strip('"').lower()
        if ALIASES.get(whole, whole) not in CANONICAL:
            name, unit = split_unit(written)
            if unit is not None:
                return unit, f"the header {written!r}"
    if layout.units is not None and layout.units[index].strip():
        unit = layout.units[index].strip().strip("[]()").strip()
        return unit.lower(), f"the units row's {layout.units[index]!r}"
    return None, ""


def scaled_columns(raw: dict[int, np.ndarray], specs: dict[str, ColumnSpec]) -> dict[str, np.ndarray]:
    """The named arrays: each mapped column times its scale plus its offset (in place when the
    column is named once)."""
    uses = [spec.index for spec in specs.values()]
    arrays = {}
    for name, spec in specs.items():
        values = raw[spec.index] if uses.count(spec.index) == 1 else raw[spec.index].copy()
        if spec.scale != 1.0:
            values *= spec.scale
        if spec.offset != 0.0:
            values += spec.offset
        arrays[name] = values
    return arrays


def _column_spec(canonical: str, name: str, spec, layout: Layout, notes: list[str], field: str) -> ColumnSpec:
    """Where and how ``canonical`` (mapped as ``name``) is read; a conversion from a unit the file or
    the mapping gives is appended to ``notes``; a unit that cannot be converted is refused naming
    ``field``."""
    header, width = layout.header, layout.width
    scale, offset, given_unit, explicit_scale = 1.0, 0.0, None, False
    if isinstance(spec, dict):
        if "column" not in spec:
            raise DataError("columns", f"{name}: a mapping object needs a 'column' key")
        try:
            scale, offset = float(spec.get("scale", 1.0)), float(spec.get("offset", 0.0))
        except (TypeError, ValueError):
            raise DataError("columns", f"{name}: scale and offset must be numbers") from None
        if not (math.isfinite(scale) and math.isfinite(offset)):
            raise DataError("columns", f"{name}: scale and offset must be finite")
        explicit_scale = "scale" in spec
        if spec.get("unit") is not None:
            if not isinstance(spec["unit"], str):
                raise DataError("columns", f'{name}: unit must be text such as "nm", not {spec["unit"]!r}')
            given_unit = spec["unit"].strip().lower()
        spec = spec["column"]
    if isinstance(spec, bool) or not isinstance(spec, (int, str)):
        raise DataError("columns", f"{name}: give a 0-based column index or a header name, not {spec!r}")
    if isinstance(spec, str):
        if header is None or spec.lower() not in header:
            raise DataError("columns", f"{name}: no column named {spec!r} in the header {layout.written}")
        index = header.index(spec.lower())
    elif not 0 <= spec < width:
        raise DataError(
            "columns", f"{name}: column {spec} does not exist; the file has {width} columns (0-based: 0..{width - 1})"
        )
    else:
        index = spec
    if explicit_scale:  # the mapping's scale is the whole conversion
        return ColumnSpec(index, scale, offset)
    unit, where = (given_unit, f"the mapping's unit {given_unit!r}") if given_unit else _written_unit(index, layout)
    if unit is None:
        return ColumnSpec(index, scale, offset)
    quantity = QUANTITY[canonical]
    factor = conversion(unit, quantity)
    if factor is None:
        other = quantity_of_unit(unit)
        what = f"a {other} unit" if other else "a unit this service does not know"
        prefix = "" if csv_name(CANONICAL[canonical]) == field else f"{name}: "
        raise DataError(
            field,
            f"{prefix}{where} gives {what}, not one of {quantity} ({known_units(quantity)}); "
            f'map the column as {{"column": {index}, "scale": <{SERVICE_UNIT[quantity]} per value>}} '
            "if it is right",
        )
    unit_scale, unit_offset = factor
    if (unit_scale, unit_offset) != (1.0, 0.0):
        notes.append(
            f"{csv_name(CANONICAL[canonical]) if canonical in CANONICAL else name}: {where} gives {unit}; "
            f"converted to {SERVICE_UNIT[quantity]}"
            + (f" (× {unit_scale:g})" if unit_offset == 0.0 else f" ({unit_offset:+g})")
        )
    return ColumnSpec(index, unit_scale, unit_offset + offset, unit)


def _name_axes(values: dict, axis: str | None) -> dict:
    """Canonical columns → internal names; ``u``/``x`` become the given axis."""
    arrays: dict = {}
    if "u" in values or "x" in values:
        if axis not in AXES:
            raise DataError(
                "axis", f"a single-axis file (columns u, x) needs axis set to one of {', '.join(AXES)}; got {axis!r}"
            )
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
