"""Cross-coupling: this axis moves with the other axis (parasitic flexure coupling). Columns: the
other axis's drive through its linear and hysteretic play operators (µm/V), and — where the data
set measured it — the other axis's displacement itself (µm/µm), which already carries that axis's
own hysteresis, creep and flexure mode (all free sign). A feedforward inverse has no measured
other-axis displacement: that column is zero there."""
from __future__ import annotations

import numpy as np

from service.science.effects.base import Effect, RecordContext
from service.science.fitting.lsq import Block


class CrossCoupling(Effect):
    name = "cross_coupling"
    signature = "this axis's residual follows the other axis's drive while this axis's own drive does not explain it"

    def blocks(self, ctx: RecordContext) -> list[Block]:
        if ctx.p_other is None:
            return [Block.make("coupling_um_per_v", np.zeros((ctx.n, 2))),
                    Block.make("coupling_um_per_um", np.zeros(ctx.n))]
        motion = ctx.x_other_um if ctx.x_other_um is not None else np.zeros(ctx.n)
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
