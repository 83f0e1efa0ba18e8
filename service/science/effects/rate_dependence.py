"""Rate dependence (paper eq. 3): the operator weights shift with u̇ and ü per segment
s(sign u̇, sign ü): α_s u̇ S + β_s ü S with S = Σ P_i (µm·s/V², µm·s²/V²), plus the rate of
each hysteretic operator Ṗ_i (i ≥ 1; viscous domain-wall motion lags the switched strain only,
not the reversible r = 0 part — which is what separates it from a pure delay)."""

from __future__ import annotations

import numpy as np

from service.science.data.units import plain
from service.science.effects.base import Effect, RecordContext
from service.science.effects.rules import growth_words, two_rates
from service.science.fitting.lsq import Block
from service.science.models.pi import segment_columns


class RateDependence(Effect):
    point_symmetric = False
    name = "rate_dependence"
    signature = (
        "the loop widens or tilts with drive rate: residual grows with frequency, "
        "changes sign with u̇ and correlates with u̇·ΣP (not with a pure shift of the whole output)"
    )

    def blocks(self, ctx: RecordContext) -> list[Block]:
        s = ctx.p.sum(axis=1)
        col_a, col_b = segment_columns(ctx.du, ctx.ddu, s)
        dp = np.gradient(ctx.p[:, 1:], 1.0 / ctx.fs_hz, axis=0) if ctx.p.shape[1] > 1 else np.zeros((ctx.n, 0))
        out = [Block.make("rate_alpha_um_per_v2_s", col_a), Block.make("rate_beta_um_per_v2_s2", col_b)]
        if dp.shape[1]:
            out.append(Block.make("rate_operator_lag_um_s_per_v", dp))
        return out

    def describe(self, theta, values):
        p = self.parameters(theta, values, {}, 1.0)
        return "" if not p else f"operator-rate weights sum {plain(p['operator_rate_weights_sum_nm_s_per_v'])} nm·s/V"

    def parameters(self, theta, values, scales, sign):
        """``operator_rate_weights_sum_nm_s_per_v``: the sum of the hysteretic operators' rate weights
        (nm·s/V), the figure the report's words print."""
        lag = values.get("rate_operator_lag_um_s_per_v")
        return {} if lag is None else {"operator_rate_weights_sum_nm_s_per_v": float(np.sum(lag)) * 1e3}

    units = {
        "rate_alpha_um_per_v2_s": "µm·s/V²",
        "rate_beta_um_per_v2_s2": "µm·s²/V²",
        "rate_operator_lag_um_s_per_v": "µm·s/V",
        "operator_rate_weights_sum_nm_s_per_v": "nm·s/V",
    }
    rule = "at least two drive rates a factor 2 apart: at one rate a rate-dependent loop is one fixed shape"
    emulator_bench = "rate_dependence"
    unseen_rate_test = True

    def untestable(self, records):
        return two_rates(self.name, records)

    def evidence(self, sig, floor):
        r = sig.get("rate_r")
        growth = growth_words(sig)
        return f"{growth}, and follows u̇·u (|r| = {r:.2f}): rate dependence" if r is not None else growth
