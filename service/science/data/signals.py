"""Commanded waveforms with analytic derivatives, turning points, and derivative estimates.

Waveforms are generic in their unit (volts for a drive, micrometres for a reference);
``value`` is in that unit, ``d1_per_s`` in unit/s and ``d2_per_s2`` in unit/s².
Pure numpy/scipy: no model, no store, no HTTP.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from drivers.jit import njit

#: A reversal counts as a turning point when it swings by this fraction of the range.
TURNING_SWING_FRACTION = 0.1
#: a half period between turning points is "steady" within this share of its neighbours' (the period
#: estimate and the segmentation of imported records both use it)
STEADY_HALF_PERIOD_SHARE = 0.2
#: Savitzky–Golay window as a fraction of the dominant period.
SAVGOL_PERIOD_FRACTION = 0.1
SAVGOL_POLYORDER = 4
#: above this window (samples) the Savitzky–Golay convolution runs by FFT (overlap-add): scipy's own
#: is direct, O(n·window). Measured on 10⁵ samples: window 81, 5.9 ms direct against 3.4 ms by FFT;
#: 2001 (a 1 Hz block at 20 kHz), 174 against 5.8 ms (a standard sweep's record: 0.7 → 0.05 s).
#: The FFT's rounding (1e-15 of u̇) moves held-out residuals by ~1e-19 µm², which the discovery
#: rule leaves out as ties (decision.TIE_SHARE).
SAVGOL_DIRECT_MAX_WINDOW = 63


@dataclass(frozen=True)
class Waveform:
    """A sampled waveform and its exact first and second time derivatives."""

    t_s: np.ndarray
    value: np.ndarray
    d1_per_s: np.ndarray
    d2_per_s2: np.ndarray
    sample_rate_hz: float


def time_axis(duration_s: float, sample_rate_hz: float) -> np.ndarray:
    """Sample instants 0, 1/fs, ... covering ``duration_s`` (s)."""
    if not sample_rate_hz > 0:
        raise ValueError(f"sample_rate_hz must be positive, got {sample_rate_hz}")
    if not duration_s > 0:
        raise ValueError(f"duration_s must be positive, got {duration_s}")
    return np.arange(int(round(duration_s * sample_rate_hz))) / sample_rate_hz


def multi_sine(
    frequencies_hz: Sequence[float],
    amplitudes: Sequence[float],
    sample_rate_hz: float,
    duration_s: float,
    low: float = 0.0,
) -> Waveform:
    """``low + Σ A_k (1 − cos 2π f_k t)``: starts at rest at ``low``, peaks at ``low + 2ΣA_k``.

    A harmonic with ``A_k f_k`` larger than the fundamental's adds minor loops of
    several amplitudes inside each major cycle.
    """
    f = np.asarray(frequencies_hz, dtype=float)[:, None]
    a = np.asarray(amplitudes, dtype=float)[:, None]
    if f.shape != a.shape:
        raise ValueError("frequencies_hz and amplitudes must have the same length")
    t = time_axis(duration_s, sample_rate_hz)
    w = 2.0 * np.pi * f
    phase = w * t[None, :]
    value = low + np.sum(a * (1.0 - np.cos(phase)), axis=0)
    d1 = np.sum(a * w * np.sin(phase), axis=0)
    d2 = np.sum(a * w**2 * np.cos(phase), axis=0)
    return Waveform(t, value, d1, d2, float(sample_rate_hz))


def biased_sine(
    frequency_hz: float,
    cycles: float,
    sample_rate_hz: float,
    low: float = 0.0,
    high: float = 120.0,
) -> Waveform:
    """The paper's drive: a sine between ``low`` and ``high`` starting at ``low`` (at rest)."""
    if not frequency_hz > 0:
        raise ValueError(f"frequency_hz must be positive, got {frequency_hz}")
    return multi_sine([frequency_hz], [(high - low) / 2.0], sample_rate_hz, cycles / frequency_hz, low)


def turning_points(y: np.ndarray, swing_fraction: float = TURNING_SWING_FRACTION) -> np.ndarray:
    """Indices of interior extrema whose prominence exceeds ``swing_fraction`` of the range."""
    y = np.asarray(y, dtype=float)
    span = float(np.ptp(y)) if y.size else 0.0
    if span == 0.0:
        return np.empty(0, dtype=int)
    prominence = swing_fraction * span
    return np.sort(np.concatenate([prominent_peaks(y, prominence), prominent_peaks(-y, prominence)]))


def prominent_peaks(y: np.ndarray, prominence: float) -> np.ndarray:
    """Indices of the local maxima of ``y`` whose prominence is at least ``prominence``: the same as
    ``scipy.signal.find_peaks(y, prominence=prominence)[0]``, in time linear in the record. (SciPy
    scans from every peak to the nearest higher sample, which is the whole record when the peaks
    are equally high, as in a clean or quantised drive: half a minute for 10 M samples.)"""
    from scipy.signal import find_peaks  # scipy.signal costs a service 0.7 s of start-up: imported when used

    y = np.ascontiguousarray(y, dtype=float)
    peaks, _ = find_peaks(y)
    if peaks.size == 0:
        return peaks
    return peaks[_prominences(y, peaks) >= prominence]


@njit(cache=True, nogil=True)
def _prominences(y, peaks):
    """Prominence of every peak (scipy's definition, no window): its height above the higher of the
    lowest points on either side before a higher sample. One pass per side with a stack of
    (height, lowest point since the peak below it on the stack): each peak is pushed and popped once."""
    n = peaks.size
    gaps = np.empty(n + 1)  # the lowest point before, between and after the peaks
    gaps[0] = y[: peaks[0] + 1].min()
    for k in range(n - 1):
        gaps[k + 1] = y[peaks[k] : peaks[k + 1] + 1].min()
    gaps[n] = y[peaks[n - 1] :].min()
    base = np.empty((2, n))
    heights, lows = np.empty(n), np.empty(n)
    for side in range(2):
        top = 0
        for j in range(n):
            k = j if side == 0 else n - 1 - j
            low = np.inf if j == 0 else (gaps[k] if side == 0 else gaps[k + 1])
            while top > 0 and heights[top - 1] <= y[peaks[k]]:
                low = min(low, lows[top - 1])
                top -= 1
            base[side, k] = min(low, gaps[0] if side == 0 else gaps[n]) if top == 0 else low
            heights[top], lows[top] = y[peaks[k]], low
            top += 1
    out = np.empty(n)
    for k in range(n):
        out[k] = y[peaks[k]] - max(base[0, k], base[1, k])
    return out


def dominant_period_samples(y: np.ndarray) -> float:
    """Dominant period (samples) from the mean spacing of turning points (two per cycle).

    Only the regular half periods count (within STEADY_HALF_PERIOD_SHARE of the median spacing), so
    a hold, or small cycles under the turning-point prominence in an amplitude ramp, do not stretch
    the period;
    when fewer than half are regular (several tones), the mean of all.
    With fewer than two interior turning points the longest monotone stretch, endpoints included,
    is taken as the half period.
    """
    y = np.asarray(y, dtype=float)
    tp = turning_points(y)
    if tp.size >= 2:
        half = np.diff(tp).astype(float)
        regular = np.abs(half - np.median(half)) <= STEADY_HALF_PERIOD_SHARE * np.median(half)
        if regular.sum() >= max(1, half.size // 2):
            return 2.0 * float(np.mean(half[regular]))
        return 2.0 * float(tp[-1] - tp[0]) / (tp.size - 1)  # no regular rhythm (several tones): the mean
    marks = np.concatenate([[0], tp, [max(y.size - 1, 1)]])
    return 2.0 * float(np.max(np.diff(marks)))


def savgol_derivatives(
    y: np.ndarray,
    sample_rate_hz: float,
    period_samples: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """First and second derivatives (unit/s, unit/s²) by Savitzky–Golay.

    The window spans ``SAVGOL_PERIOD_FRACTION`` of the dominant period (odd, at least
    polyorder + 3 samples, at most the record); short records fall back to ``np.gradient``.
    """
    y = np.asarray(y, dtype=float)
    dt = 1.0 / float(sample_rate_hz)
    if period_samples is None:
        period_samples = dominant_period_samples(y)
    window = int(round(SAVGOL_PERIOD_FRACTION * period_samples)) | 1
    window = max(window, SAVGOL_POLYORDER + 3)
    if window > y.size:
        window = y.size if y.size % 2 else y.size - 1
    if window <= SAVGOL_POLYORDER + 1:
        d1 = np.gradient(y, dt) if y.size > 1 else np.zeros_like(y)
        d2 = np.gradient(d1, dt) if y.size > 1 else np.zeros_like(y)
        return d1, d2
    return savgol(y, window, 1, dt), savgol(y, window, 2, dt)


def savgol(y: np.ndarray, window: int, deriv: int, dt_s: float) -> np.ndarray:
    """``scipy.signal.savgol_filter(y, window, SAVGOL_POLYORDER, deriv, dt_s, mode="interp")``
    (unit/s^deriv), by overlap-add FFT when the window is long (the same filter; rounding apart)."""
    from scipy.signal import oaconvolve, savgol_coeffs, savgol_filter  # see prominent_peaks

    if window <= SAVGOL_DIRECT_MAX_WINDOW:
        return savgol_filter(y, window, SAVGOL_POLYORDER, deriv=deriv, delta=dt_s, mode="interp")
    out = oaconvolve(y, savgol_coeffs(window, SAVGOL_POLYORDER, deriv=deriv, delta=dt_s), mode="same")
    # mode="interp"'s edges: the polynomial fitted to the first (last) window, at its first (last) half
    half, t = window // 2, np.arange(window)
    for fit, edge in (
        (slice(0, window), slice(0, half)),
        (slice(y.size - window, y.size), slice(window - half, window)),
    ):
        poly = np.polyder(np.polyfit(t, y[fit], SAVGOL_POLYORDER), deriv)
        out[fit][edge] = np.polyval(poly, t[edge]) / dt_s**deriv
    return out


def drive_derivatives(
    u_v: np.ndarray, sample_rate_hz: float, blocks: Sequence[dict] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """u̇ (V/s) and ü (V/s²) of a drive: the one estimator every model and record uses.

    Without ``blocks``: :func:`savgol_derivatives` over the whole drive (window from its dominant
    period). With a block table: Savitzky–Golay within each block over a window set by that
    block's own period (its frequency, else the block's dominant period), central differences
    outside the blocks.
    """
    u_v = np.asarray(u_v, dtype=float)
    if blocks is None:
        return savgol_derivatives(u_v, sample_rate_hz)
    du = np.gradient(u_v, 1.0 / sample_rate_hz)
    ddu = np.gradient(du, 1.0 / sample_rate_hz)
    for block in blocks:
        start, stop = int(block["start"]), min(int(block["stop"]), len(u_v))
        # the window of the fastest drive in the block (axes driven at once at their own frequencies)
        f_hz = max((block.get("frequencies_hz") or {}).values(), default=block.get("frequency_hz"))
        if stop - start < 8:
            continue
        period = sample_rate_hz / f_hz if f_hz else None
        du[start:stop], ddu[start:stop] = savgol_derivatives(u_v[start:stop], sample_rate_hz, period)
    return du, ddu


def sensitivity_sign(u_v: np.ndarray, x_um: np.ndarray) -> float:
    """+1 if the displacement rises with the drive (least-squares slope ≥ 0), −1 if the gauge reads
    the other way (mounted on the far side, or a negative scale). Hysteresis operators' weights are
    bounded ≥ 0, so models are fitted to sign·x and predict sign·(…)."""
    du, dx = u_v - np.mean(u_v), x_um - np.mean(x_um)
    return -1.0 if float(du @ dx) < 0 else 1.0


def longest_linked_run(linked: np.ndarray) -> tuple[int, int] | None:
    """Items i..j−1 (as ``(i, j)``) of the longest run whose successive pairs are all ``linked``
    (``linked[k]`` joins items k and k+1); None if no pair is."""
    best, start, best_span = None, None, 0
    for k, ok in enumerate(np.append(np.asarray(linked, dtype=bool), False)):
        if ok and start is None:
            start = k
        elif not ok and start is not None:
            if k - start > best_span:
                best, best_span = (start, k + 1), k - start
            start = None
    return best
