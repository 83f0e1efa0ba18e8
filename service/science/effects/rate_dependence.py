"""Rate dependence (paper eq. 3): the operator weights shift with u̇ and ü per segment
s(sign u̇, sign ü): α_s u̇ S + β_s ü S with S = Σ P_i (µm·s/V², µm·s²/V²), plus the rate of
each hysteretic operator Ṗ_i (i ≥ 1; viscous domain-wall motion lags the switched strain only,
not the reversible r = 0 part — which is what separates it from a pure delay), plus the
relaxation of the switched strain S_h = Σ_{i≥1} P_i: first-order lags of S_h with time constants
from a two-hundredth of the shortest drive period to half of it (below, a relaxation is the lag Ṗ_i
draws; above, it is creep's), weights ≥ 0 (µm/V): the relaxing share of the switched strain
follows it late, by its own time constant, at every drive rate alike."""

from __future__ import annotations

import numpy as np

from service.science.data.units import plain
from service.science.effects.base import Effect, RecordContext
from service.science.effects.creep import first_order_lowpass
from service.science.effects.rules import growth_words, two_rates
from service.science.fitting.lsq import Block
from service.science.models.pi import segment_columns

#: the fastest relaxation drawn, as a share of the shortest drive period: below it (ωτ < 0.03 at the
#: fastest drive) a relaxation acts as a pure lag, which the operator-rate columns draw
FASTEST_RELAXATION_SHARE = 1.0 / 200.0
#: the slowest, as a share of the shortest drive period: a relaxation within a period changes the
#: loop with the rate; slower ones are creep's (its lags begin at twice the period; up to 2 periods
#: here, a hidden creep of 0.3 s was also claimed as rate dependence at step 0)
SLOWEST_RELAXATION_SHARE = 0.5


def relaxation_time_constants_s(min_period_s: float, per_decade: int = 2) -> np.ndarray:
    """Time constants (s) of the switched strain's relaxation, log-spaced (``per_decade``) from
    ``FASTEST_RELAXATION_SHARE`` to ``SLOWEST_RELAXATION_SHARE`` of the shortest drive period. From
    the data set's scales only, so that a record at another sample rate gets the same columns."""
    lo, hi = FASTEST_RELAXATION_SHARE * min_period_s, SLOWEST_RELAXATION_SHARE * min_period_s
    n = max(2, int(np.ceil(np.log10(hi / lo) * per_decade)) + 1)
    return np.logspace(np.log10(lo), np.log10(hi), n)


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
            switched = s - ctx.p[:, 0]  # the hysteretic operators' sum: all but the reversible r = 0 one
            taus = relaxation_time_constants_s(ctx.min_period_s)
            relaxing = np.column_stack([first_order_lowpass(switched, tau, ctx.fs_hz) - switched for tau in taus])
            out.append(Block.make("rate_relaxation_um_per_v", relaxing, lower=0.0))
        return out

    def describe(self, theta, values):
        p = self.parameters(theta, values, {}, 1.0)
        return "" if not p else f"operator-rate weights sum {plain(p['operator_rate_weights_sum_nm_s_per_v'])} nm·s/V"

    def parameters(self, theta, values, scales, sign):
        """``operator_rate_weights_sum_nm_s_per_v``: the sum of the hysteretic operators' rate weights
        (nm·s/V), the figure the report's words print; where the switched strain relaxes,
        ``relaxing_strain_nm_per_v`` (the relaxing weights' sum, per volt of the hysteretic operators'
        sum) and ``relaxation_time_constant_us`` (their weighted geometric mean time constant)."""
        lag = values.get("rate_operator_lag_um_s_per_v")
        out = {} if lag is None else {"operator_rate_weights_sum_nm_s_per_v": float(np.sum(lag)) * 1e3}
        relaxing = np.asarray(values.get("rate_relaxation_um_per_v", []), dtype=float)
        if relaxing.size and relaxing.sum() > 0 and scales.get("min_period_s"):
            taus = relaxation_time_constants_s(scales["min_period_s"])
            out["relaxing_strain_nm_per_v"] = sign * float(relaxing.sum()) * 1e3
            mean_log_tau = float(np.sum(relaxing * np.log(taus)) / relaxing.sum())
            out["relaxation_time_constant_us"] = float(np.exp(mean_log_tau)) * 1e6
        return out

    units = {
        "rate_alpha_um_per_v2_s": "µm·s/V²",
        "rate_beta_um_per_v2_s2": "µm·s²/V²",
        "rate_operator_lag_um_s_per_v": "µm·s/V",
        "operator_rate_weights_sum_nm_s_per_v": "nm·s/V",
        "rate_relaxation_um_per_v": "µm/V",
        "relaxing_strain_nm_per_v": "nm/V",
        "relaxation_time_constant_us": "µs",
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
