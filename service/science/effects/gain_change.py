"""A gain that changes with time, without a thermometer: the stack's stroke fades (depolarisation: the
poling relaxes after power-up or a large field) or grows (self-heating raises d33) in proportion to the
time since the record started, x(t) = x_stack·(1 + g·t).

Columns: the time since the record started (s, scaled by the longest record) times the normalised drive
u/u_max and the normalised hysteretic state S/u_max (S = Σ_{i≥1} P_i, the play operators above the
first), as the temperature effect scales the loop with ΔT: two weights (µm over the longest record), so
that it cannot give each block (each at its own time in a long record) a loop shape of its own, as one
column per operator did (11.0 → 11.4 nm held out on a Bouc–Wen β > γ stage). No t·1 column: an
output that moves whatever the displacement is ``drift`` (additive in time), and one that relaxes after
each step of the drive, logarithmically in time, is ``creep``; a gain change is zero where the stack is
at rest and grows with the displacement. The held-out cycles are later in time than the training ones,
so a claim is a prediction forwards in time.
"""

from __future__ import annotations

import numpy as np

from service.science.effects.base import Effect, RecordContext
from service.science.fitting.lsq import Block
from service.science.models.base import equal_thresholds

#: a gain change needs this long a record to show (s): 0.1 %/s over 2 s is 0.2 % of the stroke
MIN_DURATION_S = 2.0


def state_rise_on_branch(n_operators: int, u_scale_v: float) -> float:
    """The rise of S/u_max on the loop's ascending branch from the drive's origin to its full scale, in
    the steady state (after a descent from the top), the branch the base's ``stroke_um`` is read on:
    Σ_{i≥1} max(1 − 2·r_i/u_max, 0) over ``n_operators`` play operators with thresholds r_i equally
    spaced from 0 to half the drive scale."""
    r = equal_thresholds(u_scale_v, n_operators)[1:] / u_scale_v
    return float(np.sum(np.maximum(1.0 - 2.0 * r, 0.0)))


class GainChange(Effect):
    name = "gain_change"
    signature = (
        "the error grows in proportion to the displacement and to time: the stack's gain changes over "
        "the run (zero at rest, largest at full drive, late in the record)"
    )
    units = {"gain_change_um": "µm", "gain_change_pct_per_s": "%/s", "gain_change_pct": "%"}
    rule = (
        f"a record of at least {MIN_DURATION_S:g} s that drives the stack over a range; telling it from drift "
        "needs the drive to change level (a gain change is zero at rest), from creep a long hold"
    )
    sweep = {"waveform": "sine", "frequencies_hz": [1.0, 10.0], "cycles": 20}
    emulator_bench = "gain_change"
    separated_from = {
        "drift": (
            "a long sine run with rests between blocks: a gain change scales the loop and vanishes at rest, "
            "drift moves the output at rest too",
            {"waveform": "sine", "frequencies_hz": [1.0, 10.0], "cycles": 20},
        ),
        "creep": (
            "a step-hold sweep up and down: creep relaxes logarithmically after each step and reverses when "
            "the drive steps down; a gain change grows steadily with time at every level",
            {"waveform": "step", "level_shares": [5 / 6, 1 / 6, 5 / 6, 1 / 6], "hold_s": 4.0},
        ),
    }

    def blocks(self, ctx: RecordContext) -> list[Block]:
        t = ctx.t_s / ctx.time_scale_s
        u = ctx.u_v / ctx.u_scale_v
        s = ctx.p[:, 1:].sum(axis=1) / ctx.u_scale_v if ctx.p.shape[1] > 1 else u
        return [Block.make("gain_change_um", np.column_stack([t * u, t * s]))]

    def untestable(self, records) -> str | None:
        longest = max((r.n_samples / r.sample_rate_hz for r in records), default=0.0)
        if longest >= MIN_DURATION_S:
            return None
        return (
            f"a gain change needs a record of at least {MIN_DURATION_S:g} s (the longest here is {longest:.3g} s): "
            "record the blocks one after the other in one long record"
        )

    def parameters(self, theta, values, scales, sign):
        """``gain_change_pct_per_s``: the change of the stroke (the loop's rise from the drive's origin to its
        full scale, ``stroke_um``) per second, as a share of it (%/s; negative: the gain fades);
        ``gain_change_pct`` over the longest record."""
        change, stroke_um = values.get("gain_change_um"), scales.get("stroke_um")
        weights = values.get("weights_um_per_v")
        if change is None or not stroke_um or weights is None:
            return {}
        at_full = float(change[0]) + float(change[1]) * state_rise_on_branch(len(weights), scales["u_scale_v"])
        share = at_full / stroke_um  # over the longest record
        return {"gain_change_pct": 100 * share, "gain_change_pct_per_s": 100 * share / scales["time_scale_s"]}

    def describe(self, theta, values):
        change = values.get("gain_change_um")
        return "" if change is None else f"the loop's weights change by {float(np.sum(change)) * 1e3:.4g} nm in all"

    def evidence(self, sig, floor):
        return (
            "the residual grows with time in proportion to the displacement (zero at rest, largest at full drive): "
            "a gain that changes over the run — depolarisation or self-heating, no thermometer needed: gain_change"
        )
