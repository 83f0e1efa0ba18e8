"""Noise floor and repeatability from the data itself.

Each block's residual is cut into whole cycles (resampled to an integer number of points per
cycle when the period is fractional, by windowed-sinc interpolation: a linear one averaged
neighbouring samples, so the noise came out √(2/3) low, and bent every cycle's curved stretches
differently, which the symmetry test read as an asymmetric loop); the first cycle (start-up
transient) is dropped when three or more remain. ``noise_um`` comes from the differences of successive cycles, each with
its own mean and slope removed (slow drift/creep is reported as ``slow_rms_um``, not as noise),
as the median over cycle pairs; ``repeatable_um`` = RMS of the mean cycle with the noise's share
(σ²/N) removed, a part of ``cycles_rms_um`` (the residual's RMS over the same cycles). Only pairs whose drive repeated count (drive difference ≤ 1 % of its swing): in an
amplitude ramp or across a hold, the residual changes because the drive did, which is not noise.
With no such pair the noise comes from second differences of the residual.
"""

from __future__ import annotations

import numpy as np

from service.science.data.signals import longest_linked_run

#: half-width (samples) of the windowed-sinc (Lanczos) kernel that resamples cycles of a fractional period
SINC_HALF_WIDTH = 8
#: resampled points per step of the interpolation (bounds its temporary arrays to a few MB)
RESAMPLE_CHUNK = 1 << 16


def cycles_matrix(r: np.ndarray, period_samples: float, even: bool = False) -> np.ndarray | None:
    """(N, M) whole cycles of ``r`` (None if fewer than two); ``even``: M even, so that a half cycle
    is M/2 points (an odd or fractional period is resampled)."""
    got = _cycles(r, period_samples, even)
    return None if got is None else got[0]


def _cycles(r: np.ndarray, period_samples: float, even: bool = False) -> tuple[np.ndarray, np.ndarray | None] | None:
    """(cycles (N, M), noise gain (N, M): the variance of white noise at each resampled point over
    the samples', None where no point was resampled), None if fewer than two whole cycles."""
    n_cycles = int(np.floor(r.size / period_samples + 1e-9))
    if n_cycles < 2:
        return None
    m = int(round(period_samples))
    whole = abs(period_samples - m) < 1e-6
    if even and m % 2:
        m, whole = m + 1, False
    if whole:
        mat, gain = r[: n_cycles * m].reshape(n_cycles, m), None
    else:
        at = np.arange(n_cycles)[:, None] * period_samples + np.arange(m)[None, :] * (period_samples / m)
        mat, gain = (v.reshape(n_cycles, m) for v in sinc_resample(r, at.ravel()))
    keep = slice(1, None) if n_cycles >= 3 else slice(None)
    return mat[keep], None if gain is None else gain[keep]


def sinc_resample(r: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``r`` at the fractional sample positions ``at`` (Lanczos kernel of SINC_HALF_WIDTH lobes, its
    weights summing to 1, the record's end samples repeated beyond it), and each value's noise gain
    Σw² (white noise of variance σ² has variance Σw²·σ² there: 0.92–1 for this kernel)."""
    taps = np.arange(-SINC_HALF_WIDTH + 1, SINC_HALF_WIDTH + 1)
    values, gains = np.empty(at.size), np.empty(at.size)
    for lo in range(0, at.size, RESAMPLE_CHUNK):
        where = at[lo : lo + RESAMPLE_CHUNK]
        base = np.floor(where).astype(np.int64)
        x = taps[None, :] - (where - base)[:, None]
        w = np.sinc(x) * np.sinc(x / SINC_HALF_WIDTH)
        w /= w.sum(axis=1, keepdims=True)
        values[lo : lo + where.size] = np.sum(r[np.clip(base[:, None] + taps[None, :], 0, r.size - 1)] * w, axis=1)
        gains[lo : lo + where.size] = np.sum(w * w, axis=1)
    return values, gains


#: successive cycles count as "the same drive" when their drive differs by at most this share of its swing
SAME_DRIVE_SHARE = 0.01


def repeatability(r: np.ndarray, period_samples: float, drive: np.ndarray | None = None) -> dict:
    """``noise_um``, ``repeatable_um``, ``slow_rms_um``, ``cycles`` of one block's residual ``r``
    (µm); ``drive`` (same length, any unit) restricts the noise to cycles whose drive repeated."""
    got = None if not period_samples else _cycles(r, period_samples)
    mat, gain = got if got is not None else (None, None)
    why = "no period (not a periodic drive)" if not period_samples else "fewer than two whole cycles"
    if mat is not None and drive is not None:
        run = longest_linked_run(repeated_cycles(cycles_matrix(np.asarray(drive, dtype=float), period_samples)))
        why = "no two successive cycles with the same drive"
        mat = None if run is None else mat[run[0] : run[1]]
        gain = None if gain is None or run is None else gain[run[0] : run[1]]
    if mat is None:
        d2 = np.diff(r, 2)
        sigma = float(np.std(d2) / np.sqrt(6.0)) if d2.size > 2 else float("nan")
        return {
            "noise_um": sigma,
            "repeatable_um": None,
            "cycles_rms_um": None,
            "slow_rms_um": None,
            "cycles": 0,
            "method": f"second differences ({why})",
        }
    n, m = mat.shape
    mean_cycle = mat.mean(axis=0)
    dev = mat - mean_cycle
    s = np.linspace(-1.0, 1.0, m)
    slow = _mean_and_slope(dev, s)
    lag = None if gain is None else aligned_lag(period_samples, r.size)
    lagged = None if lag is None else _lagged_noise_variance(r, period_samples, lag, drive)
    var = lagged if lagged is not None else _successive_cycle_variance(mat, s, gain)
    rep2 = float(np.mean(mean_cycle**2)) - var / n
    return {
        "noise_um": float(np.sqrt(var)),
        "repeatable_um": float(np.sqrt(max(rep2, 0.0))),
        "cycles_rms_um": float(np.sqrt(np.mean(mat**2))),  # the whole the repeatable part is of (≥ it)
        "slow_rms_um": float(np.sqrt(np.mean(slow**2))),
        "cycles": int(n),
        "method": "cycle-to-cycle repeatability",
    }


#: a fractional period's noise is measured between cycles q ≤ MAX_ALIGNED_CYCLES apart whose
#: distance is a whole number of samples (to ALIGNED_SAMPLES)
MAX_ALIGNED_CYCLES = 16
ALIGNED_SAMPLES = 1e-3


def aligned_lag(period_samples: float, samples: int) -> int | None:
    """The shortest distance (samples) of q ≥ 1 whole cycles that is a whole number of samples
    (38.46 samples a cycle: 13 cycles, 500 samples; 976.5625: 16 cycles), if a block of
    ``samples`` holds two periods' more than it; None otherwise."""
    for q in range(1, MAX_ALIGNED_CYCLES + 1):
        lag = q * period_samples
        if abs(lag - round(lag)) <= ALIGNED_SAMPLES and samples >= round(lag) + 2 * period_samples:
            return int(round(lag))
    return None


def _lagged_noise_variance(r: np.ndarray, period_samples: float, lag: int, drive: np.ndarray | None) -> float | None:
    """Noise variance (µm²) from r(t + lag) − r(t), the same phase of cycles ``lag`` samples apart:
    no sample is interpolated. Cut into stretches of a period, each detrended; the median over the
    stretches whose drive repeated (as ``repeated_cycles``); None if none did."""
    m = int(round(period_samples))
    d = r[lag:] - r[:-lag]
    k = d.size // m
    rows = d[: k * m].reshape(k, m)
    if drive is not None:
        drive = np.asarray(drive, dtype=float)
        change = drive[lag:][: k * m].reshape(k, m) - drive[:-lag][: k * m].reshape(k, m)
        same = np.sqrt(np.mean(change**2, axis=1)) <= SAME_DRIVE_SHARE * (float(np.ptp(drive)) or 1.0)
        rows = rows[same]
    if not rows.size:
        return None
    s = np.linspace(-1.0, 1.0, m)
    rest = rows - _mean_and_slope(rows, s)
    return float(np.median(np.sum(rest**2, axis=1) / max(m - 2, 1) / 2.0))


def repeated_cycles(drive_mat: np.ndarray) -> np.ndarray:
    """(N−1,) bool: successive cycles i, i+1 of the drive that repeat (RMS difference ≤
    SAME_DRIVE_SHARE of the drive's swing over the block)."""
    swing = float(np.ptp(drive_mat)) or 1.0
    change = np.sqrt(np.mean(np.diff(drive_mat, axis=0) ** 2, axis=1))
    return change <= SAME_DRIVE_SHARE * swing


def _mean_and_slope(rows: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Each row's own mean and slope over the cycle phase ``s`` ∈ [-1, 1]."""
    return rows.mean(axis=1, keepdims=True) + (rows @ s)[:, None] / np.sum(s * s) * s


def _successive_cycle_variance(mat: np.ndarray, s: np.ndarray, gain: np.ndarray | None = None) -> float:
    """Noise variance (µm²) from the differences of successive cycles, each detrended: white noise
    gives var(diff) = 2σ² per pair (resampled cycles: the two points' noise gains instead of 2). The
    median over pairs ignores a pair that still carries a start-up transient (ringing, settling),
    which is repeatable later and not noise."""
    diff = np.diff(mat, axis=0)
    rest = diff - _mean_and_slope(diff, s)
    pair_gain = 2.0 if gain is None else np.mean(gain[1:] + gain[:-1], axis=1)
    per_pair = np.sum(rest**2, axis=1) / max(mat.shape[1] - 2, 1) / pair_gain
    return float(np.median(per_pair))


def noise_floor(records, residuals, rests: dict | None = None) -> dict:
    """Per block figures; the floor is the median over blocks (robust to one block whose
    non-repeatable part is inflated, e.g. ringing near a resonance), the repeatable part their mean.
    With ``rests`` (service.science.discovery.rests.read_rests: the record's rests) the floor is what
    the gauge shows at rest less the disturbance's lines (removed from the records before the model
    is judged), and the blocks' median is kept as ``cycles_noise_um``."""
    per_block = []
    for rec, res in zip(records, residuals):
        for s in rec.splits:
            a, b = s.train[0], s.held_out[1]
            fig = repeatability(res[a:b], rec.period_samples(s), rec.u_v[a:b])
            per_block.append(
                {
                    "dataset_id": rec.label,
                    "index": s.block.get("index"),
                    "frequency_hz": s.block.get("frequency_hz"),
                    **fig,
                }
            )
    noise = [b["noise_um"] for b in per_block if np.isfinite(b["noise_um"])]
    rep = [b["repeatable_um"] for b in per_block if b["repeatable_um"] is not None]
    whole = [b["cycles_rms_um"] for b in per_block if b["repeatable_um"] is not None]
    cycles = float(np.median(noise)) if noise else None
    return {
        "noise_floor_um": rests["noise_um"] if rests else cycles,
        "source": "rests" if rests else "cycles",
        "cycles_noise_um": cycles,
        "rest_seconds": rests["seconds"] if rests else None,
        "repeatable_rms_um": float(np.mean(rep)) if rep else None,
        # the residual's RMS over the same cycles (quadratic mean over the same blocks): never below the
        # repeatable part (mean ≤ quadratic mean, and each block's repeatable part ≤ its cycles' RMS)
        "repeated_cycles_rms_um": float(np.sqrt(np.mean(np.square(whole)))) if whole else None,
        "per_block": per_block,
    }
