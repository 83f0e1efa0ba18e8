"""Noise floor and repeatability from the data itself.

Each block's residual is cut into whole cycles (resampled to an integer number of points per
cycle when the period is fractional); the first cycle (start-up transient) is dropped when
three or more remain. ``noise_um`` comes from the differences of successive cycles, each with
its own mean and slope removed (slow drift/creep is reported as ``slow_rms_um``, not as noise),
as the median over cycle pairs; ``repeatable_um`` = RMS of the mean cycle with the noise's share
(σ²/N) removed. Only pairs whose drive repeated count (drive difference ≤ 1 % of its swing): in an
amplitude ramp or across a hold, the residual changes because the drive did, which is not noise.
With no such pair the noise comes from second differences of the residual.
"""
from __future__ import annotations

import numpy as np

from service.science.data.signals import longest_linked_run


def cycles_matrix(r: np.ndarray, period_samples: float) -> np.ndarray | None:
    """(N, M) whole cycles of ``r`` (None if fewer than two)."""
    n_cycles = int(np.floor(r.size / period_samples + 1e-9))
    if n_cycles < 2:
        return None
    m = int(round(period_samples))
    if abs(period_samples - m) < 1e-6:
        mat = r[: n_cycles * m].reshape(n_cycles, m)
    else:
        idx = np.arange(n_cycles)[:, None] * period_samples + np.arange(m)[None, :] * (period_samples / m)
        mat = np.interp(idx.ravel(), np.arange(r.size), r).reshape(n_cycles, m)
    return mat[1:] if n_cycles >= 3 else mat


#: successive cycles count as "the same drive" when their drive differs by at most this share of its swing
SAME_DRIVE_SHARE = 0.01


def repeatability(r: np.ndarray, period_samples: float, drive: np.ndarray | None = None) -> dict:
    """``noise_um``, ``repeatable_um``, ``slow_rms_um``, ``cycles`` of one block's residual ``r``
    (µm); ``drive`` (same length, any unit) restricts the noise to cycles whose drive repeated."""
    mat = None if not period_samples else cycles_matrix(r, period_samples)
    why = "no period (not a periodic drive)" if not period_samples else "fewer than two whole cycles"
    if mat is not None and drive is not None:
        same = repeated_cycles(cycles_matrix(np.asarray(drive, dtype=float), period_samples))
        mat, why = _longest_run(mat, same), "no two successive cycles with the same drive"
    if mat is None:
        d2 = np.diff(r, 2)
        sigma = float(np.std(d2) / np.sqrt(6.0)) if d2.size > 2 else float("nan")
        return {"noise_um": sigma, "repeatable_um": None, "slow_rms_um": None, "cycles": 0,
                "method": f"second differences ({why})"}
    n, m = mat.shape
    mean_cycle = mat.mean(axis=0)
    dev = mat - mean_cycle
    s = np.linspace(-1.0, 1.0, m)
    slow = _mean_and_slope(dev, s)
    var = _successive_cycle_variance(mat, s)
    rep2 = float(np.mean(mean_cycle**2)) - var / n
    return {"noise_um": float(np.sqrt(var)), "repeatable_um": float(np.sqrt(max(rep2, 0.0))),
            "slow_rms_um": float(np.sqrt(np.mean(slow**2))), "cycles": int(n),
            "method": "cycle-to-cycle repeatability"}


def repeated_cycles(drive_mat: np.ndarray) -> np.ndarray:
    """(N−1,) bool: successive cycles i, i+1 of the drive that repeat (RMS difference ≤
    SAME_DRIVE_SHARE of the drive's swing over the block)."""
    swing = float(np.ptp(drive_mat)) or 1.0
    change = np.sqrt(np.mean(np.diff(drive_mat, axis=0) ** 2, axis=1))
    return change <= SAME_DRIVE_SHARE * swing


def _longest_run(mat: np.ndarray, same: np.ndarray) -> np.ndarray | None:
    """The longest run of successive cycles whose drive repeated (None if no pair did)."""
    run = longest_linked_run(same)
    return None if run is None else mat[run[0]:run[1]]


def _mean_and_slope(rows: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Each row's own mean and slope over the cycle phase ``s`` ∈ [-1, 1]."""
    return rows.mean(axis=1, keepdims=True) + (rows @ s)[:, None] / np.sum(s * s) * s


def _successive_cycle_variance(mat: np.ndarray, s: np.ndarray) -> float:
    """Noise variance (µm²) from the differences of successive cycles, each detrended: white noise
    gives var(diff) = 2σ² per pair. The median over pairs ignores a pair that still carries a
    start-up transient (ringing, settling), which is repeatable later and not noise."""
    diff = np.diff(mat, axis=0)
    rest = diff - _mean_and_slope(diff, s)
    per_pair = np.sum(rest**2, axis=1) / max(mat.shape[1] - 2, 1) / 2.0
    return float(np.median(per_pair))


def noise_floor(records, residuals) -> dict:
    """Per block figures; the floor is the median over blocks (robust to one block whose
    non-repeatable part is inflated, e.g. ringing near a resonance), the repeatable part their mean."""
    per_block = []
    for rec, res in zip(records, residuals):
        for s in rec.splits:
            a, b = s.train[0], s.held_out[1]
            fig = repeatability(res[a:b], rec.period_samples(s), rec.u_v[a:b])
            per_block.append({"dataset_id": rec.label, "index": s.block.get("index"),
                              "frequency_hz": s.block.get("frequency_hz"), **fig})
    noise = [b["noise_um"] for b in per_block if np.isfinite(b["noise_um"])]
    rep = [b["repeatable_um"] for b in per_block if b["repeatable_um"] is not None]
    return {"noise_floor_um": float(np.median(noise)) if noise else None,
            "repeatable_rms_um": float(np.mean(rep)) if rep else None, "per_block": per_block}
