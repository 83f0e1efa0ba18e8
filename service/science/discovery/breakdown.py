"""Where a model fails: its held-out residual broken down by frequency, loop branch and segment
(signs of u̇, ü), turning points, amplitude, and time; and the signature numbers each effect's
evidence quotes (lag, growth with frequency, trends, symmetry, coupling)."""

from __future__ import annotations

import numpy as np

from service.science.data.holdout import other_axes
from service.science.data.units import fmt_nm
from service.science.discovery.rests import at_rest_level, still_mask
from service.science.fitting.metrics import rms
from service.science.models.kernels import segment_index

SEGMENTS = ("rising, accelerating", "rising, decelerating", "falling, accelerating", "falling, decelerating")


def _held_rows(rec) -> np.ndarray:
    mask = np.zeros(rec.n_samples, dtype=bool)
    for s in rec.splits:
        mask[s.held_out[0] : s.held_out[1]] = True
    return mask


#: a block is a step-hold when its drive is still over at least this share of its samples
HOLD_SHARE = 0.5


def _is_step_hold(rec, a: int, b: int) -> bool:
    """Samples a..b are a step-hold: the drive steps (moves over more than a rest's level) and is held
    still over at least HOLD_SHARE of them."""
    moves = b > a and not at_rest_level(rec)[a:b].all()
    return bool(moves and float(np.mean(still_mask(rec)[a:b])) >= HOLD_SHARE)


def _holds_outside_blocks(rec) -> np.ndarray:
    """Rows outside every block where the drive is held still away from its rest level (the model runs
    through them, never fitted there)."""
    outside = np.ones(rec.n_samples, dtype=bool)
    for s in rec.splits:
        outside[s.train[0] : s.held_out[1]] = False
    return outside & still_mask(rec) & ~at_rest_level(rec)


def failures(records, residuals, top: int = 6) -> list[dict]:
    """The worst places of the held-out residual, worst first, each in words and numbers; a block's
    place also names it (``record``: the record's label, ``block_index``, ``frequency_hz``)."""
    places = []
    for rec, res in zip(records, residuals):
        held = _held_rows(rec)
        seg = segment_index(np.ascontiguousarray(rec.du_v_per_s), np.ascontiguousarray(rec.ddu_v_per_s2))
        for s in rec.splits:
            rows = slice(*s.held_out)
            f = s.block.get("frequency_hz")
            where = f"{f:g} Hz block" if f else f"block {s.block.get('index')}"
            if _is_step_hold(rec, s.train[0], s.held_out[1]):
                where = (
                    f"step-hold block {s.block.get('index')} (levels held, read as {f:g} Hz)"
                    if f
                    else f"step-hold block {s.block.get('index')}"
                    + (f" (the hold at {s.block['level_v']:.4g} V)" if s.block.get("level_v") is not None else "")
                )
            if others := other_axes(s.block, rec.axis):  # the other axis's block: cross-coupling's place
                where += f" that drives {'/'.join(a.upper() for a in others)} ({rec.axis.upper()} undriven)"
            places.append(
                (
                    f"{rec.label} {where}",
                    rms(res[rows]),
                    "frequency",
                    {"record": rec.label, "block_index": s.block.get("index"), "frequency_hz": f},
                )
            )
        outside = _holds_outside_blocks(rec)
        if outside.any():  # never fitted: held out as a whole
            places.append(
                (
                    f"{rec.label} holds outside the blocks ({outside.sum() / rec.sample_rate_hz:.3g} s)",
                    rms(res[outside]),
                    "holds",
                    {"record": rec.label},
                )
            )
        for k, name in enumerate(SEGMENTS):
            m = held & (seg == k)
            places.append((f"{rec.label} {name} branch", rms(res[m]), "branch", {}))
        speed = np.abs(rec.du_v_per_s)
        slow = held & (speed < 0.1 * np.percentile(speed[held], 95))
        places.append((f"{rec.label} turning points (|u̇| < 10 % of its peak)", rms(res[slow]), "turning points", {}))
        lo, hi = np.percentile(rec.u_v[held], [33, 67])
        for name, m in (("low third of the drive", rec.u_v < lo), ("top third of the drive", rec.u_v > hi)):
            bound = f"u {'<' if 'low' in name else '>'} {lo if 'low' in name else hi:.3g} V"
            places.append((f"{rec.label} {name} ({bound})", rms(res[held & m]), "amplitude", {}))
    places.sort(key=lambda p: -p[1])
    return [
        {"where": w, "rms_um": round(v, 6), "by": by, **block, "text": f"{w}: held-out residual RMS {fmt_nm(v)}"}
        for w, v, by, block in places[:top]
    ]


def visible_lags(lags: list[tuple]) -> dict:
    """Per drive frequency (None: a block without one), the slope-weighted mean lag (s) of its blocks and
    their weight (Σ (dx̂/dt)², µm²/s²), for the frequencies where a lag is visible (5 % of the largest
    weight). The overall lag is their weighted mean, so it lies among the per-block figures printed
    beside it (it was the mean of every block's, and "26 µs" stood beside blocks that one frequency's
    several blocks overwrote)."""
    sums: dict = {}
    for f, lag_s, weight in lags:
        wv, w = sums.get(f, (0.0, 0.0))
        sums[f] = (wv + weight * lag_s, w + weight)
    per = {f: (wv / w, w) for f, (wv, w) in sums.items() if w > 0}
    largest = max((w for _, w in per.values()), default=0.0)
    return {f: vw for f, vw in per.items() if vw[1] >= 0.05 * largest}


def mean_lag_s(by_frequency: dict) -> float:
    """The weighted mean (s) of ``visible_lags``'s per-frequency lags."""
    lag_s, weight = np.array(list(by_frequency.values())).T
    return float(np.average(lag_s, weights=weight))


def signatures(records, residuals, predictions) -> dict:
    """Numbers the evidence strings quote, from the current model's residual on every block."""
    lags, rms_f, trend, logslope, even, coupling, rate_r = [], [], [], [], [], [], []
    for rec, res, pred in zip(records, residuals, predictions):
        dpred = np.gradient(pred, 1.0 / rec.sample_rate_hz)
        s_rate = rec.du_v_per_s * (rec.u_v - rec.u_v.min())
        for s in rec.splits:
            a, b = s.train[0], s.held_out[1]
            r, d = res[a:b] - res[a:b].mean(), dpred[a:b]
            f = s.block.get("frequency_hz")
            moves = np.ptp(rec.u_v[a:b]) > 1e-6
            if moves and np.dot(d, d) > 0:
                design = np.column_stack([np.ones(b - a), pred[a:b], d])  # r ≈ c + g·x̂ − τ·dx̂/dt
                lags.append((f, float(-np.linalg.lstsq(design, res[a:b], rcond=None)[0][2]), float(np.dot(d, d))))
                rms_f.append((f, rms(r)))
                if np.std(s_rate[a:b]) > 0 and np.std(r) > 0:
                    rate_r.append(abs(float(np.corrcoef(r, s_rate[a:b])[0, 1])))
                u = rec.u_v[a:b]
                centre = 0.5 * (u.max() + u.min())
                uu = (u - centre) / max(0.5 * np.ptp(u), 1e-9)
                c = np.polyfit(uu, r, 2)
                even.append(float(np.sqrt(np.mean((c[0] * (uu**2 - np.mean(uu**2))) ** 2)) / max(rms(r), 1e-300)))
                period = int(round(rec.period_samples(s) or (b - a)))
                n_cyc = (b - a) // max(period, 1)
                if n_cyc >= 2:
                    means = res[a : a + n_cyc * period].reshape(n_cyc, period).mean(axis=1)
                    tc = (np.arange(n_cyc) + 0.5) * period / rec.sample_rate_hz
                    trend.append(float(np.polyfit(tc, means, 1)[0]))
                    logslope.append(float(np.polyfit(np.log10(tc), means, 1)[0]))
            elif rec.u_other_v is not None and np.ptp(rec.u_other_v[a:b]) > 1e-6 and np.std(r) > 0:
                coupling.append(float(np.corrcoef(r, rec.u_other_v[a:b])[0, 1]))
    freqs = [f for f, _, _ in lags if f]
    growth = None
    if len({f for f, _ in rms_f if f}) >= 2:
        fr = np.array([[f, v] for f, v in rms_f if f and v > 0])
        growth = float(np.polyfit(np.log(fr[:, 0]), np.log(fr[:, 1]), 1)[0])
    by_frequency = visible_lags(lags)
    return {
        "lag_ms_by_frequency": {f"{f:g}" if f else "record": round(v * 1e3, 4) for f, (v, _) in by_frequency.items()},
        "lag_ms_spread": float(np.std([v for v, _ in by_frequency.values()]) * 1e3) if by_frequency else None,
        "lag_ms": mean_lag_s(by_frequency) * 1e3 if by_frequency else None,
        "rms_growth_exponent": growth,
        "frequencies_hz": sorted(set(freqs)),
        "cycle_mean_trend_um_per_s": float(np.median(trend)) if trend else None,
        "cycle_mean_um_per_decade": float(np.median(logslope)) if logslope else None,
        "even_fraction": float(np.median(even)) if even else None,
        "coupling_r": float(np.median(coupling)) if coupling else None,
        "rate_r": float(np.median(rate_r)) if rate_r else None,
    }
