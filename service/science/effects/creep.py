"""Creep: the strain keeps moving after the drive stops, logarithmically in time.

A log(t) response needs several decades of relaxation times: the drive is passed through
first-order low-pass filters with time constants log-spaced (2 per decade) from twice the
shortest drive period up to half the longest record (the same set for every record); their weights (µm/V) come from least squares, bounded ≥ 0: creep always continues in the
direction of the last drive change (it reverses when the drive steps down), which a slow drift
of the lab or the gauge does not.
"""

from __future__ import annotations

import numpy as np

from service.science.data.units import fmt_nm
from service.science.effects.base import Effect, RecordContext
from service.science.fitting.lsq import Block


def creep_time_constants_s(min_period_s: float, duration_s: float, per_decade: int = 2) -> np.ndarray:
    lo, hi = 2.0 * min_period_s, max(4.0 * min_period_s, 0.5 * duration_s)
    n = max(2, int(np.ceil(np.log10(hi / lo) * per_decade)) + 1)
    return np.logspace(np.log10(lo), np.log10(hi), n)


def first_order_lowpass(x: np.ndarray, tau_s: float, fs_hz: float) -> np.ndarray:
    """Exact-discretised first-order lag of unit DC gain, starting at rest."""
    a = np.exp(-1.0 / (tau_s * fs_hz))
    from scipy.signal import lfilter  # imported when used: scipy.signal costs a service 0.7 s of start-up

    return lfilter([1.0 - a], [1.0, -a], x, axis=0)


class Creep(Effect):
    name = "creep"
    gain_change_test = True
    signature = (
        "the residual keeps moving after each change of the drive level, roughly linearly "
        "in log(time); per-cycle mean residual rises with log(t) within each block"
    )

    def blocks(self, ctx: RecordContext) -> list[Block]:
        taus = creep_time_constants_s(ctx.min_period_s, ctx.time_scale_s)
        u0 = ctx.u_v / ctx.u_scale_v
        cols = np.column_stack([first_order_lowpass(u0, tau, ctx.fs_hz) - u0 for tau in taus])
        return [Block.make("creep_weights_um", cols, lower=0.0)]

    def describe(self, theta, values):
        return ""

    def parameters(self, theta, values, scales, sign):
        """``creep_nm_per_decade``: after a step of the full drive scale (``creep_step_v``), the mean rise
        of the output per decade of time between the shortest and the longest relaxation time (nm);
        ``creep_pct_per_decade``: that rise as a share of the hysteresis base's stroke (``stroke_um``)."""
        weights = values.get("creep_weights_um")
        if weights is None:
            return {}
        taus = creep_time_constants_s(scales["min_period_s"], scales["time_scale_s"])
        risen = lambda t_s: float(np.sum(np.asarray(weights) * (1.0 - np.exp(-t_s / taus))))  # noqa: E731
        per_decade_um = float((risen(taus[-1]) - risen(taus[0])) / np.log10(taus[-1] / taus[0]))
        out = {"creep_nm_per_decade": sign * per_decade_um * 1e3, "creep_step_v": float(scales["u_scale_v"])}
        if scales.get("stroke_um"):
            out["creep_pct_per_decade"] = 100.0 * per_decade_um / scales["stroke_um"]
        return out

    units = {
        "creep_weights_um": "µm",
        "creep_nm_per_decade": "nm/decade",
        "creep_step_v": "V",
        "creep_pct_per_decade": "%/decade",
    }
    rule = "any record long enough to see a slow change; telling it from drift needs a hold after a step"
    emulator_bench = "creep"
    separated_from = {
        "drift": (
            "a step-hold sweep up and down: creep relaxes logarithmically after each "
            "step and reverses when the drive steps down; drift keeps its direction "
            "and pace regardless of the steps",
            {"waveform": "step", "level_shares": [5 / 6, 1 / 6, 5 / 6, 1 / 6], "hold_s": 4.0},
        )
    }

    def evidence(self, sig, floor):
        v = sig.get("cycle_mean_um_per_decade")
        return (
            "the per-cycle mean residual moves "
            + (fmt_nm(v) if v is not None else "?")
            + " per decade of time within each block, logarithmic in time: creep"
        )
