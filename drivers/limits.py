"""Limit checks of a Bench: whole-waveform refusal, per-command clamping (actuator volts, V/s, A).

``LimitsMixin`` expects ``self.limits`` (axis → AxisLimits); ``drivers.bench.Bench`` inherits it.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from drivers.interfaces import LimitError

#: the paper's identification range (V): a bench config without a stack rating keeps it
PAPER_V_MIN = 0.0
PAPER_V_MAX = 120.0
# A sampled waveform's finite-difference slope overshoots the analytic one by rounding
# and quantisation; allow this relative margin before calling it a limit violation.
_RATE_CHECK_MARGIN = 1.02
# A non-resonant device works below its first resonance; a sine above this fraction of it
# rings the flexure (and its harmonics sit on the mode), so it is refused.
RESONANCE_FRACTION = 0.5


def highest_sine_hz(lim, vpp_v: float) -> float:
    """The largest sine frequency (Hz) an axis with limits ``lim`` (AxisLimits) allows at ``vpp_v``:
    the amplifier's current and slew at that swing, and RESONANCE_FRACTION × the first resonance."""
    resonance = lim.first_resonance_hz
    cap = RESONANCE_FRACTION * resonance if np.isfinite(resonance) else float("inf")
    return float(min(lim.max_frequency_hz(vpp_v), cap))


def stack_rating_v(config: dict, axis: str) -> tuple[float, float]:
    """(min, max) V the axis's stack is rated for: ``[axes.<axis>.piezo] rated_min_v, rated_max_v``
    of the bench config (0–150 V for the default bench's PTJ150 on a PZD350); a config without
    them (a bare test rig) is held to the paper's 0–120 V."""
    piezo = config.get("axes", {}).get(axis, {}).get("piezo", {})
    return float(piezo.get("rated_min_v", PAPER_V_MIN)), float(piezo.get("rated_max_v", PAPER_V_MAX))


class LimitsMixin:
    """Voltage, slew-rate, current and resonance limits per axis (see ``AxisLimits``)."""

    def max_frequency_hz(self, axis: str, vpp_v: float) -> float:
        """Largest sine frequency at ``vpp_v`` that the amplifier can drive into the stack."""
        return self.limits[self._axis(axis)].max_frequency_hz(vpp_v)

    def check_sine(self, axis: str, vpp_v: float, frequency_hz: float) -> None:
        """Refuse a sine whose peak current or slew rate exceeds the amplifier's limits, or whose
        frequency comes within reach of the axis's first resonance."""
        lim = self.limits[self._axis(axis)]
        need_a = np.pi * frequency_hz * vpp_v * lim.capacitance_f
        if need_a > lim.current_limit_a:
            raise LimitError(
                f"{vpp_v:g} Vpp at {frequency_hz:g} Hz needs {need_a * 1e3:.0f} mA; the amplifier's "
                f"limit is {lim.current_limit_a * 1e3:.0f} mA (largest frequency at this amplitude, within "
                f"every limit of the axis: {highest_sine_hz(lim, vpp_v):.1f} Hz)"
            )
        slew = np.pi * frequency_hz * vpp_v
        if slew > lim.slew_limit_v_per_s:
            raise LimitError(
                f"{vpp_v:g} Vpp at {frequency_hz:g} Hz slews at {slew / 1e3:.1f} V/ms; the amplifier's "
                f"limit is {lim.slew_limit_v_per_s / 1e3:.1f} V/ms"
            )
        if np.isfinite(lim.first_resonance_hz) and frequency_hz > RESONANCE_FRACTION * lim.first_resonance_hz:
            raise LimitError(
                f"{frequency_hz:g} Hz is above {RESONANCE_FRACTION:g} × the {axis} axis's first resonance "
                f"({lim.first_resonance_hz:g} Hz); a non-resonant drive must stay below "
                f"{RESONANCE_FRACTION * lim.first_resonance_hz:.1f} Hz"
            )

    def check_waveform(self, u_v: Mapping[str, np.ndarray], sample_rate_hz: float) -> None:
        """Refuse a planned waveform that would leave the limits. Raises LimitError saying why."""
        if sample_rate_hz <= 0 or not np.isfinite(sample_rate_hz):
            raise LimitError(f"sample rate {sample_rate_hz} Hz must be a positive number")
        for axis, u in u_v.items():
            lim = self.limits[self._axis(axis)]
            u = np.asarray(u, dtype=float)
            if u.ndim != 1 or len(u) == 0:
                raise LimitError(f"u_{axis} must be a non-empty 1-D array of volts")
            if not np.all(np.isfinite(u)):
                raise LimitError(f"u_{axis} contains NaN or infinite values")
            if u.max() > lim.v_max_v or u.min() < lim.v_min_v:
                raise LimitError(
                    f"u_{axis} spans {u.min():.1f}–{u.max():.1f} V; the actuator limit is "
                    f"{lim.v_min_v:g}–{lim.v_max_v:g} V"
                )
            if len(u) > 1:
                rate = float(np.max(np.abs(np.diff(u)))) * sample_rate_hz
                need_a = rate * lim.capacitance_f
                if need_a > lim.current_limit_a * _RATE_CHECK_MARGIN:
                    raise LimitError(
                        f"u_{axis} changes at up to {rate / 1e3:.1f} V/ms, which needs {need_a * 1e3:.0f} mA "
                        f"into {lim.capacitance_f * 1e6:.2f} µF; the amplifier's limit is "
                        f"{lim.current_limit_a * 1e3:.0f} mA"
                    )
                if rate > lim.slew_limit_v_per_s * _RATE_CHECK_MARGIN:
                    raise LimitError(
                        f"u_{axis} changes at up to {rate / 1e3:.1f} V/ms; the amplifier's slew limit is "
                        f"{lim.slew_limit_v_per_s / 1e3:.1f} V/ms"
                    )

    def clamp(self, axis: str, u_v: float, previous_v: float, dt_s: float) -> float:
        """Clamp one command to the voltage range and to the largest step the limits allow."""
        lim = self.limits[axis]
        max_step = dt_s * lim.max_rate_v_per_s
        u = min(max(u_v, previous_v - max_step), previous_v + max_step)
        return min(max(u, lim.v_min_v), lim.v_max_v)

    def clamp_block(self, axis: str, u_v: np.ndarray, previous_v: float, sample_rate_hz: float) -> np.ndarray:
        """Vector form of ``clamp`` for a block of commands (sequential because of the rate limit)."""
        lim = self.limits[axis]
        u = np.clip(np.nan_to_num(np.asarray(u_v, dtype=float), nan=0.0), lim.v_min_v, lim.v_max_v)
        max_step = lim.max_rate_v_per_s / sample_rate_hz
        steps = np.diff(np.concatenate(([previous_v], u)))
        if np.all(np.abs(steps) <= max_step):
            return u
        out = np.empty_like(u)
        prev = previous_v
        for k, target in enumerate(u):  # rare path: only when a block violates the rate limit
            prev = min(max(target, prev - max_step), prev + max_step)
            out[k] = prev
        return out

    def _axis(self, axis: str) -> str:
        if axis not in self.limits:
            raise LimitError(f"unknown axis {axis!r}; this bench has {', '.join(self.axes)}")
        return axis
