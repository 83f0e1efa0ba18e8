"""Cross-coupling: this axis moves with the other axis (parasitic flexure coupling). Columns: the
other axis's drive through its linear and hysteretic play operators (µm/V), and — where the data
set measured it and the other axis was driven — the other axis's displacement itself (µm/µm), which
already carries that axis's own hysteresis, creep and flexure mode (all free sign). A feedforward inverse has no measured
other-axis displacement: that column is zero there."""

from __future__ import annotations

import numpy as np

from service.science.effects.base import Effect, RecordContext
from service.science.effects.rules import RATE_SWEEP, independent_other_axis
from service.science.fitting.lsq import Block

#: the other axis counts as driven where its drive is away from its level at the record's start (rest)
#: by more than this share of its span
DRIVEN_SHARE = 0.005


def other_axis_driven(u_other_v: np.ndarray) -> np.ndarray:
    """Rows (bool) where the other axis's drive (V) is away from its starting (rest) level. Only there
    can its measured motion cause this axis's: where it rests, its motion is this axis's coupling
    into it (a reaction, µm/µm of this axis's own output), and as a regressor it would explain this
    axis by its own echo (a Z sweep on the default bench fitted 37 µm/µm and left the inverse no
    hysteresis to invert)."""
    u = np.asarray(u_other_v, dtype=float)
    span = float(np.ptp(u)) if u.size else 0.0
    if span == 0.0:
        return np.zeros(u.size, dtype=bool)
    return np.abs(u - u[0]) > DRIVEN_SHARE * span


class CrossCoupling(Effect):
    name = "cross_coupling"
    signature = "this axis's residual follows the other axis's drive while this axis's own drive does not explain it"

    def blocks(self, ctx: RecordContext) -> list[Block]:
        if ctx.p_other is None:
            return [
                Block.make("coupling_um_per_v", np.zeros((ctx.n, 2))),
                Block.make("coupling_um_per_um", np.zeros(ctx.n)),
            ]
        motion = (
            np.zeros(ctx.n)
            if ctx.x_other_um is None
            else np.where(other_axis_driven(ctx.u_other_v), ctx.x_other_um, 0.0)
        )
        drive = np.column_stack([ctx.p_other[:, 0], ctx.p_other[:, 1:].sum(axis=1)])
        return [Block.make("coupling_um_per_v", drive), Block.make("coupling_um_per_um", motion)]

    def parameters(self, theta, values, scales, sign):
        """``coupling_ratio``: this axis's motion per µm of the other axis's measured motion (µm/µm);
        ``coupling_drive_um_per_v`` and ``coupling_hysteretic_um_per_v``: the other axis's drive path
        (its linear and summed hysteretic play-operator weights)."""
        out = {}
        if values.get("coupling_um_per_um") is not None:
            out["coupling_ratio"] = sign * float(np.asarray(values["coupling_um_per_um"]).ravel()[0])
        drive = values.get("coupling_um_per_v")
        if drive is not None:
            out["coupling_drive_um_per_v"], out["coupling_hysteretic_um_per_v"] = (sign * float(w) for w in drive)
        return out

    units = {
        "coupling_um_per_v": "µm/V",
        "coupling_um_per_um": "µm/µm",
        "coupling_ratio": "µm/µm",
        "coupling_drive_um_per_v": "µm/V",
        "coupling_hysteretic_um_per_v": "µm/V",
    }
    rule = (
        "the other axis driven independently of this one: with collinear drives coupling is "
        "indistinguishable from more hysteresis"
    )
    sweep = {**RATE_SWEEP, "together": False}
    sweep_both_axes = True
    emulator_bench = "cross_coupling"

    def untestable(self, records):
        return independent_other_axis(records)

    def evidence(self, sig, floor):
        r = sig.get("coupling_r")
        return (
            f"this axis's residual follows the other axis's drive, r = {r:.2f}: cross-coupling"
            if r is not None
            else "no block drives the other axis alone, so coupling cannot be seen directly"
        )
