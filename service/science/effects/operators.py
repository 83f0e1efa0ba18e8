"""Model capacity, not a physical effect: twice as many play operators (finer thresholds) and a
second family of play operators on a warped drive u·|u|/u_max. The warp lets the operator density
vary along the drive (as a generalised PI's envelope does), which equal-threshold operators on u
alone cannot: a loop whose shape is wrong at every frequency alike is a capacity problem."""
from __future__ import annotations

import numpy as np

from service.science.effects.base import Effect, RecordContext
from service.science.models.base import equal_thresholds
from service.science.models.kernels import play_operators
from service.science.fitting.lsq import Block

OPERATOR_FACTOR = 2


class Operators(Effect):
    name = "operators"
    kind = "capacity"
    stage = "capacity"
    signature = ("the loop shape itself is not matched (residual repeats cycle to cycle, at all "
                 "frequencies alike): more or finer play operators; a model-capacity change, not physics")

    def blocks(self, ctx: RecordContext) -> list[Block]:
        """Play operators (µm/V weights, free sign: a correction to the main family) of the warped
        drive u·|u|/u_max (V), thresholds as the main family's over the data set's drive scale."""
        warped_v = ctx.u_v * np.abs(ctx.u_v) / ctx.u_scale_v
        thresholds = equal_thresholds(ctx.u_scale_v, ctx.p.shape[1])
        return [Block.make("warped_weights_um_per_v", play_operators(warped_v, thresholds))]
