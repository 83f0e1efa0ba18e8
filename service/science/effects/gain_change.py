"""A gain that changes with time, without a thermometer: the stack's stroke fades (depolarisation: the
poling relaxes after power-up or a large field) or grows (self-heating raises d33) in proportion to the
time since the record started, x(t) = x_stack·(1 + g·t).

Columns: the time since the record started (s, scaled by the longest record) times each play operator's
output (normalised by the drive scale): the hysteresis base's own columns, changing with time, so the
fitted weights are the change of each operator's weight over the longest record (µm). No t·1 column: an
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


def stroke_share(weights: np.ndarray, u_scale_v: float) -> float:
    """Σ w_i·max(1 − r_i/u_scale, 0): the output (in units of w) of play operators with weights ``w``
    (per unit of normalised output) loaded from rest to the full drive scale, thresholds r_i equally
    spaced from 0 to half the drive scale."""
    r = equal_thresholds(u_scale_v, weights.size) / u_scale_v
    return float(np.dot(weights, np.maximum(1.0 - r, 0.0)))


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
            {"waveform": "step", "levels_v": [100.0, 20.0, 100.0, 20.0], "hold_s": 4.0},
        ),
    }

    def blocks(self, ctx: RecordContext) -> list[Block]:
        t = ctx.t_s / ctx.time_scale_s
        return [Block.make("gain_change_um", t[:, None] * ctx.p / ctx.u_scale_v)]

    def untestable(self, records) -> str | None:
        longest = max((r.n_samples / r.sample_rate_hz for r in records), default=0.0)
        if longest >= MIN_DURATION_S:
            return None
        return (
            f"a gain change needs a record of at least {MIN_DURATION_S:g} s (the longest here is {longest:.3g} s): "
            "record the blocks one after the other in one long record"
        )

    def parameters(self, theta, values, scales, sign):
        """``gain_change_pct_per_s``: the change of the stroke from rest to the full drive scale per second,
        as a share of the stroke (%/s; negative: the gain fades); ``gain_change_pct`` over the longest record."""
        change, stroke_um = values.get("gain_change_um"), scales.get("stroke_um")
        if change is None or not stroke_um:
            return {}
        share = stroke_share(np.asarray(change), scales["u_scale_v"]) / stroke_um  # over the longest record
        return {"gain_change_pct": 100 * share, "gain_change_pct_per_s": 100 * share / scales["time_scale_s"]}

    def describe(self, theta, values):
        change = values.get("gain_change_um")
        return "" if change is None else f"the operators' weights change by {float(np.sum(change)) * 1e3:.4g} nm in all"

    def evidence(self, sig, floor):
        return (
            "the residual grows with time in proportion to the displacement (zero at rest, largest at full drive): "
            "a gain that changes over the run — depolarisation or self-heating, no thermometer needed: gain_change"
        )
