"""Units written into other labs' column names, and the conversion to this service's units.

Exports name their columns with a unit in many ways: ``Time [ms]``, ``Voltage (V)``,
``Displacement/nm``, ``x_y_nm``, ``t in s``, or a units row under the header. An import that
ignored them stored milliseconds as seconds and nanometres as micrometres, a silent factor of 1000.
Here a column name is split into its name and its unit, and the unit into a factor (and, for
kelvin, an offset) to seconds, volts, micrometres or degrees Celsius. A unit that is not one of the
column's quantity is an error, never a guess.
"""

from __future__ import annotations

import math
import re

#: quantity → unit (lower case) → (scale, offset): value in the service's unit = value·scale + offset
UNITS_OF = {
    "time": {
        "s": (1.0, 0.0),
        "sec": (1.0, 0.0),
        "ms": (1e-3, 0.0),
        "us": (1e-6, 0.0),
        "µs": (1e-6, 0.0),
        "μs": (1e-6, 0.0),
        "ns": (1e-9, 0.0),
        "min": (60.0, 0.0),
    },
    "voltage": {"v": (1.0, 0.0), "mv": (1e-3, 0.0), "kv": (1e3, 0.0)},
    "length": {
        "m": (1e6, 0.0),
        "mm": (1e3, 0.0),
        "um": (1.0, 0.0),
        "µm": (1.0, 0.0),
        "μm": (1.0, 0.0),
        "micron": (1.0, 0.0),
        "microns": (1.0, 0.0),
        "microm": (1.0, 0.0),
        "nm": (1e-3, 0.0),
        "pm": (1e-6, 0.0),
    },
    "temperature": {"c": (1.0, 0.0), "°c": (1.0, 0.0), "degc": (1.0, 0.0), "deg c": (1.0, 0.0), "k": (1.0, -273.15)},
}
#: the service's unit of each quantity, as messages name it
SERVICE_UNIT = {"time": "s", "voltage": "V", "length": "µm", "temperature": "°C"}

# "name [unit]", "name (unit)", "name {unit}", "name / unit", "name in unit"
_WRITTEN_UNIT = (
    re.compile(r"^(?P<name>.*?)\s*[\[({]\s*(?P<unit>[^\])}]*?)\s*[\])}]\s*$"),
    re.compile(r"^(?P<name>.*?)\s*/\s*(?P<unit>[^/]+?)\s*$"),
    re.compile(r"^(?P<name>.*?)\s+in\s+(?P<unit>\S+)\s*$", re.IGNORECASE),
)
_ALL_UNITS = {unit for units in UNITS_OF.values() for unit in units}


def split_unit(written: str) -> tuple[str, str | None]:
    """A column name as written → (its name, lower case and stripped; its unit, lower case, or None).
    ``'Time [ms]'`` → ``('time', 'ms')``; ``'x_y_nm'`` → ``('x_y', 'nm')`` (a ``_unit`` suffix counts
    only when it is a known unit); ``'temp_c'`` → ``('temp', 'c')``: callers look the whole name up
    first."""
    text = written.strip().strip('"').strip()
    for pattern in _WRITTEN_UNIT:
        match = pattern.match(text)
        if match and match["name"].strip():
            return match["name"].strip().lower(), match["unit"].strip().lower()
    name, _, suffix = text.lower().rpartition("_")
    if name and suffix in _ALL_UNITS:
        return name, suffix
    return text.lower(), None


def conversion(unit: str, quantity: str) -> tuple[float, float] | None:
    """(scale, offset) from ``unit`` to the service's unit of ``quantity``; None if ``unit`` is not
    one of that quantity's."""
    return UNITS_OF[quantity].get(unit.strip().lower())


def quantity_of_unit(unit: str) -> str | None:
    """The quantity ``unit`` measures (time, voltage, length, temperature), or None if unknown."""
    return next((q for q, units in UNITS_OF.items() if unit.strip().lower() in units), None)


def known_units(quantity: str) -> str:
    """The units of ``quantity`` a message can offer, e.g. ``s, ms, us, ns``."""
    return ", ".join(u for u in UNITS_OF[quantity] if u.isascii() and u not in ("sec", "microns", "microm", "deg c"))


#: below this magnitude a figure is printed as 0 (a fit's rounding: 1e-300 would be 300 digits)
PLAIN_ZERO = 1e-12


def plain(value: float, digits: int = 3) -> str:
    """``value`` to ``digits`` significant digits in positional notation, never an exponent
    (4.11e-05 → "0.0000411", 5150.4 → "5150", 6.4e6 → "6400000"); "–" for no value."""
    if value is None or not math.isfinite(value):
        return "–"
    rounded = float(f"{float(value):.{digits}g}")
    if abs(rounded) < PLAIN_ZERO:
        return "0"
    text = f"{rounded:.{max(digits - 1 - math.floor(math.log10(abs(rounded))), 0)}f}" if rounded else "0"
    return text.rstrip("0").rstrip(".") if "." in text else text


def fmt_nm(value_um: float | None, digits: int = 3) -> str:
    """An error or noise figure given in µm, as text in nm: the one unit for errors and noise wherever
    the user reads them (the API's texts, the CLI, the report); ``digits`` significant digits, never an
    exponent (0.002945 → "2.94 nm", 6.4 → "6400 nm"); "–" for no value."""
    return "–" if value_um is None or not math.isfinite(value_um) else f"{plain(value_um * 1e3, digits)} nm"


#: a mean square below this (nm²) is printed as 0: a fit's rounding, not a figure (−1.1e-11 nm²)
NM2_RESOLUTION = 1e-3


def fmt_nm2(value_um2: float | None, digits: int = 3) -> str:
    """A mean square of errors given in µm², as text in nm² (5.15e-3 → "5150 nm²"), never an exponent."""
    if value_um2 is None or not math.isfinite(value_um2):
        return "–"
    nm2 = value_um2 * 1e6
    return f"{plain(nm2 if abs(nm2) >= NM2_RESOLUTION else 0.0, digits)} nm²"


def fmt_us(value_s: float | None, digits: int = 3) -> str:
    """A delay or lag given in s, as text in µs, the one unit for delays (2.41e-5 → "24.1 µs")."""
    return "–" if value_s is None or not math.isfinite(value_s) else f"{plain(value_s * 1e6, digits)} µs"
