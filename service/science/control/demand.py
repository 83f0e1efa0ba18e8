"""What a tracking run will ask of the hardware, predicted before it runs from the identified plant
(its flexure mode included) and the planned feedforward drive.

The fixed rule it replaces ("a non-resonant drive stays below 0.5 × the first resonance") is a rule
of thumb for a drive that does not know the mode. A feedforward that inverts the identified mode
(service.science.discovery.composite_inverse, step 1: the planned reference's spectrum divided by the
mode's response, exact for a reference that is periodic between rest and rest) shapes the drive so
that the mode's gain is undone; what limits the frequency is then the hardware: the amplifier's
current into the stack's capacitance (i = C·du/dt), its slew rate and the voltage range. Per axis:

- the reference's and the drive's amplitude at every harmonic of the trajectory frequency up to
  ``BAND_OVER_MODE`` × the mode, with the mode's gain there;
- the peak current C·max|du/dt| (A) and slew max|du/dt| (V/s) of the drive over its steady periods,
  against ``CURRENT_HEADROOM`` × the amplifier's limits (the PID and the learning ride on the drive);
- the drive's range (V) against the axis's voltage limits.

Units: µm, V, A, V/s, Hz.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from service.science.control.stability import AxisPlant, plant_response

#: the harmonics a prediction lists reach this multiple of the axis's mode
BAND_OVER_MODE = 1.25
#: at most this many harmonics are listed (a mode far above the trajectory)
MAX_LISTED_HARMONICS = 12
#: the share of the amplifier's current and slew limits the feedforward may use: the rest is the
#: headroom of the PID's and the learning's corrections, which ride on it
CURRENT_HEADROOM = 0.9
#: a drive this far (V) beyond the voltage limits is within the model's error (as safety.STROKE_TOLERANCE_V)
VOLTAGE_TOLERANCE_V = 1.0


@dataclass(frozen=True)
class AxisDemand:
    """One axis's predicted demand: ``harmonics`` [{k, frequency_hz, reference_um, mode_gain,
    drive_v}] (amplitudes, µm and V), the peak current (A) and slew (V/s) of the steady drive with
    the amplifier's limits, and the drive's range (V) with the axis's voltage limits."""

    axis: str
    harmonics: tuple
    peak_current_a: float
    current_limit_a: float
    peak_slew_v_per_s: float
    slew_limit_v_per_s: float
    drive_v: tuple[float, float]
    limits_v: tuple[float, float]

    def as_dict(self) -> dict:
        return asdict(self)

    def exceeded(self, voltage_tolerance_v: float = VOLTAGE_TOLERANCE_V) -> list[str]:
        """The limits this demand exceeds (the voltage range by more than ``voltage_tolerance_v``; inf:
        not judged), in words with the figure, the limit and by how much."""
        out = []
        allowed_a = CURRENT_HEADROOM * self.current_limit_a
        if self.peak_current_a > allowed_a:
            out.append(
                f"peak current {self.peak_current_a * 1e3:.0f} mA (C·du/dt of the mode-inverting drive) exceeds "
                f"{CURRENT_HEADROOM:g} × the amplifier's {self.current_limit_a * 1e3:.0f} mA limit "
                f"({allowed_a * 1e3:.0f} mA) by {100 * (self.peak_current_a / allowed_a - 1):.0f} %"
            )
        allowed_slew = CURRENT_HEADROOM * self.slew_limit_v_per_s
        if self.peak_slew_v_per_s > allowed_slew:
            out.append(
                f"slew {self.peak_slew_v_per_s / 1e3:.1f} kV/s exceeds {CURRENT_HEADROOM:g} × the amplifier's "
                f"{self.slew_limit_v_per_s / 1e3:.1f} kV/s limit by "
                f"{100 * (self.peak_slew_v_per_s / allowed_slew - 1):.0f} %"
            )
        lo, hi = self.drive_v
        beyond = max(hi - self.limits_v[1], self.limits_v[0] - lo)
        if beyond > voltage_tolerance_v:
            out.append(
                f"drive {lo:.1f}–{hi:.1f} V leaves the axis's {self.limits_v[0]:g}–{self.limits_v[1]:g} V "
                f"limits by {beyond:.1f} V"
            )
        return out


def harmonic_amplitudes(signal: np.ndarray, period: int, harmonics: int) -> np.ndarray:
    """Amplitudes (the signal's unit) of harmonics 1..``harmonics`` of whole periods of ``signal``."""
    m = len(signal) // period
    spectrum = np.fft.rfft(np.asarray(signal[: m * period], dtype=float).reshape(m, period), axis=1).mean(axis=0)
    return 2.0 * np.abs(spectrum[1 : harmonics + 1]) / period


def listed_harmonics(mode: tuple[float, float] | None, frequency_hz: float, period: int) -> int:
    """How many harmonics reach BAND_OVER_MODE × the ``mode`` (Hz, ζ) (at least the fundamental)."""
    if mode is None or not np.isfinite(mode[0]):
        return 1
    top = int(np.ceil(BAND_OVER_MODE * mode[0] / frequency_hz))
    return int(np.clip(top, 1, min(MAX_LISTED_HARMONICS, period // 2)))


def predict_demand(
    axis: str,
    limits,
    x_ref_um: np.ndarray,
    u_v: np.ndarray,
    mode: tuple[float, float] | None,
    frequency_hz: float,
    period: int,
    sample_rate_hz: float,
) -> AxisDemand:
    """``AxisDemand`` of the steady reference ``x_ref_um`` (µm) and its planned drive ``u_v`` (V), whole
    periods of ``period`` samples, on an axis of ``limits`` (drivers.bench.AxisLimits) whose identified
    flexure ``mode`` is (Hz, damping ratio)."""
    k = listed_harmonics(mode, frequency_hz, period)
    f = frequency_hz * np.arange(1, k + 1)
    gain = np.ones(k) if mode is None else np.abs(plant_response(AxisPlant(1.0, mode[0], mode[1], 0.0), f))
    x_amp, u_amp = harmonic_amplitudes(x_ref_um, period, k), harmonic_amplitudes(u_v, period, k)
    rows = tuple(
        {
            "k": i + 1,
            "frequency_hz": float(f[i]),
            "reference_um": float(x_amp[i]),
            "mode_gain": float(gain[i]),
            "drive_v": float(u_amp[i]),
        }
        for i in range(k)
    )
    slew = float(np.max(np.abs(np.diff(u_v)))) * sample_rate_hz if len(u_v) > 1 else 0.0
    return AxisDemand(
        axis,
        rows,
        slew * limits.capacitance_f,
        limits.current_limit_a,
        slew,
        limits.slew_limit_v_per_s,
        (float(np.min(u_v)), float(np.max(u_v))),
        (limits.v_min_v, limits.v_max_v),
    )


def demand_refusal(
    demands: list[AxisDemand], frequency_hz: float, voltage_tolerance_v=VOLTAGE_TOLERANCE_V
) -> str | None:
    """Why the hardware cannot run this trajectory (the axes, figures, limits and by how much), or None.
    ``voltage_tolerance_v``: V, or axis → V (inf: that axis's voltage is not judged here)."""
    tol = voltage_tolerance_v if isinstance(voltage_tolerance_v, dict) else {}
    said = {d.axis: d.exceeded(tol.get(d.axis, voltage_tolerance_v) if tol else voltage_tolerance_v) for d in demands}
    parts = [f"axis {axis}: " + "; ".join(why) for axis, why in said.items() if why]
    if not parts:
        return None
    return f"at {frequency_hz:g} Hz, predicted from the identified plant: " + "; ".join(parts)
