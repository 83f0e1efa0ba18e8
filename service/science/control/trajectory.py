"""Elliptical references in the YOZ plane with smooth start and stop ramps.

The ellipse's long axis makes ``inclination_deg`` with Z. Each axis is a sine at
``frequency_hz`` whose span (µm) and minimum come from the range form ``y_range_um=(1, 6)``
or the amplitude form (peak-to-peak ``amplitude_y_um`` above ``min_y_um``, default 1 µm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.science.errors import FieldError

#: Longest run (s): 600 s at 20 kHz is 12 M samples per axis, about 0.5 GB of traces while it runs.
MAX_DURATION_S = 600.0
RAMP_PERIODS = 3  # raised-cosine start and stop ramps, in periods each


@dataclass(frozen=True)
class Ellipse:
    """Ranges in µm (min, max) per axis, inclination in degrees, frequency in Hz, steady cycles."""

    y_range_um: tuple[float, float]
    z_range_um: tuple[float, float]
    inclination_deg: float = 0.0
    frequency_hz: float = 100.0
    cycles: int = 50

    def semi_axes_um(self) -> tuple[float, float]:
        """(long, short) semi-axes (µm) giving the per-axis amplitudes at this inclination."""
        ay = 0.5 * (self.y_range_um[1] - self.y_range_um[0])
        az = 0.5 * (self.z_range_um[1] - self.z_range_um[0])
        th = np.radians(self.inclination_deg)
        c2, s2 = np.cos(th) ** 2, np.sin(th) ** 2
        det = c2 - s2
        if abs(det) < 1e-9:
            raise FieldError("inclination_deg", "45° leaves the semi-axes undetermined by the ranges")
        with np.errstate(over="ignore", invalid="ignore"):  # huge spans: refused just below
            a2 = (az * az * c2 - ay * ay * s2) / det
            b2 = (ay * ay * c2 - az * az * s2) / det
        if not (np.isfinite(a2) and np.isfinite(b2)):
            raise FieldError("y_range_um", f"spans of {2 * ay:g} µm (Y) and {2 * az:g} µm (Z) are too large to sample")
        if a2 < 0 or b2 < 0 or (a2 < b2):
            raise FieldError(
                "inclination_deg",
                f"no ellipse inclined {self.inclination_deg:g}° to Z has "
                f"a Y span of {2 * ay:g} µm and a Z span of {2 * az:g} µm" + _span_ratio_hint(ay, az, th),
            )
        return float(np.sqrt(a2)), float(np.sqrt(b2))

    @property
    def peak_to_peak_um(self) -> dict[str, float]:
        return {"y": self.y_range_um[1] - self.y_range_um[0], "z": self.z_range_um[1] - self.z_range_um[0]}


def _span_ratio_hint(ay: float, az: float, th: float) -> str:
    """What spans an ellipse at inclination ``th`` (rad, |th| < 45°) can have: its Z span lies between
    its Y span and cot|th| times it (semi-spans ``ay``, ``az`` in µm)."""
    if abs(np.tan(th)) < 1e-12 or abs(th) >= np.pi / 4:
        return ""
    bound = 1.0 / abs(np.tan(th))
    return (
        f": inclined {np.degrees(abs(th)):g}°, the Z span lies between the Y span and {bound:.3g}× it "
        f"(here {az / ay:.3g}×); change a span or the inclination"
        if ay > 0
        else ""
    )


def validate(e: Ellipse) -> None:
    """FieldError naming the field when the request makes no sense."""
    for name, (lo, hi) in (("y_range_um", e.y_range_um), ("z_range_um", e.z_range_um)):
        if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo or lo < 0:
            raise FieldError(name, f"needs 0 <= min < max, got [{lo}, {hi}]")
    if not 0 < e.frequency_hz <= 1000:
        raise FieldError("frequency_hz", f"must lie in (0, 1000] Hz, got {e.frequency_hz}")
    if not 1 <= e.cycles <= 10_000:
        raise FieldError("cycles", f"must lie in 1–10000, got {e.cycles}")
    duration_s = (e.cycles + 2 * RAMP_PERIODS) / e.frequency_hz
    if duration_s > MAX_DURATION_S:
        raise FieldError(
            "cycles",
            f"{e.cycles} cycles at {e.frequency_hz:g} Hz (with the start and stop ramps) "
            f"last {duration_s:.3g} s; a trajectory may last at most {MAX_DURATION_S:g} s",
        )
    if not -90 <= e.inclination_deg <= 90:
        raise FieldError("inclination_deg", f"must lie in −90–90°, got {e.inclination_deg}")
    e.semi_axes_um()


@dataclass
class Reference:
    """Sampled reference: ``x_um`` (n, 2) columns Y, Z; ``period`` samples per cycle; ramp and
    steady segments in periods; ``envelope`` (n,) the ramp window (0 at rest, 1 in steady state)."""

    x_um: np.ndarray
    envelope: np.ndarray
    sample_rate_hz: float
    period: int
    ramp_periods: int
    cycles: int

    @property
    def periods(self) -> int:
        return 2 * self.ramp_periods + self.cycles

    @property
    def steady(self) -> slice:
        """The samples of the steady periods (between the ramps)."""
        return slice(self.ramp_periods * self.period, (self.ramp_periods + self.cycles) * self.period)

    def steady_period(self) -> np.ndarray:
        """One steady-state period (period, 2) in µm."""
        return self.x_um[self.steady][: self.period]


def reference(e: Ellipse, sample_rate_hz: float, ramp_periods: int = RAMP_PERIODS) -> Reference:
    """Sample the ellipse; the frequency must give a whole number of samples per period.

    Ramps are raised-cosine windows over ``ramp_periods`` on the centre and the amplitude, so
    the start and end are at 0 µm with zero slope."""
    validate(e)
    period = int(round(sample_rate_hz / e.frequency_hz))
    if abs(period * e.frequency_hz - sample_rate_hz) > 1e-6 * sample_rate_hz:
        raise FieldError(
            "frequency_hz", f"{e.frequency_hz:g} Hz is not a whole number of samples at {sample_rate_hz:g} Hz"
        )
    periods = 2 * ramp_periods + e.cycles
    n = periods * period
    phase = 2 * np.pi * np.arange(n) / period
    a, b = e.semi_axes_um()
    th = np.radians(e.inclination_deg)
    y = a * np.sin(th) * np.cos(phase) + b * np.cos(th) * np.sin(phase)
    z = a * np.cos(th) * np.cos(phase) - b * np.sin(th) * np.sin(phase)
    cy, cz = np.mean(e.y_range_um), np.mean(e.z_range_um)
    env = np.ones(n)
    r = ramp_periods * period
    if r:
        w = 0.5 - 0.5 * np.cos(np.pi * np.arange(r) / r)
        env[:r] = w
        env[n - r :] = w[::-1]
    x = np.stack([env * (cy + y), env * (cz + z)], axis=1)
    return Reference(
        x_um=x,
        envelope=env,
        sample_rate_hz=float(sample_rate_hz),
        period=period,
        ramp_periods=ramp_periods,
        cycles=e.cycles,
    )
