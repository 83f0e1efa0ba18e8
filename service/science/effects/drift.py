"""Drift: a slow output change unrelated to the drive (thermal or gauge offset drift):
Legendre polynomials of degree 1..3 of the time since the record started, scaled by the longest
record, so a drift rate (µm/s) is shared by records of different lengths and every record starts
from the same drift state (the shared offset) (µm)."""

from __future__ import annotations

import numpy as np
from numpy.polynomial import legendre

from service.science.data.units import plain
from service.science.effects.base import Effect, RecordContext
from service.science.fitting.lsq import Block

DEGREE = 3


class Drift(Effect):
    name = "drift"
    gain_change_test = True
    signature = (
        "the per-cycle mean residual moves steadily with time over the whole record, "
        "independent of the drive level and of when the drive changed"
    )

    def blocks(self, ctx: RecordContext) -> list[Block]:
        s = 2.0 * ctx.t_s / ctx.time_scale_s - 1.0
        cols = np.column_stack([legendre.legval(s, np.eye(DEGREE + 1)[k]) for k in range(1, DEGREE + 1)])
        return [Block.make("drift_legendre_um", cols)]

    def parameters(self, theta, values, scales, sign):
        """``drift_nm_per_s``: the mean rate over the longest record (the Legendre terms' end-to-end
        change, P_k(1) − P_k(−1) = 1 − (−1)^k, over its duration)."""
        c = values.get("drift_legendre_um")
        if c is None:
            return {}
        change_um = sum(float(ck) * (1.0 - (-1.0) ** k) for k, ck in enumerate(c, start=1))
        return {"drift_nm_per_s": sign * change_um / scales["time_scale_s"] * 1e3}

    units = {"drift_legendre_um": "µm", "drift_nm_per_s": "nm/s"}
    rule = "any record long enough to see a slow change; telling it from creep needs a hold after a step"
    emulator_bench = "drift"

    def evidence(self, sig, floor):
        v = sig.get("cycle_mean_trend_um_per_s")
        return (
            "the per-cycle mean residual keeps moving at "
            + (f"{plain(v * 1e3)} nm/s" if v is not None else "?")
            + " over the run: drift"
        )
