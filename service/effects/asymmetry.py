"""Asymmetry: a loop that is not point-symmetric. Electrostriction adds strain ∝ u² (and u³);
the switched (hysteretic) strain saturates, a smooth odd-and-even function of itself (S², S³)
whose size depends on the field (u·S). Columns in the normalised drive u/u_max and the
normalised hysteretic state S = Σ_{i≥1} P_i / u_max."""
from __future__ import annotations

import numpy as np

from service.effects.base import Effect, RecordContext
from service.identification.lsq import Block


class Asymmetry(Effect):
    name = "asymmetry"
    signature = ("the branch-mean residual is an even (parabolic) or saturating function of the "
                 "drive: the loop is not point-symmetric about its centre")

    def blocks(self, ctx: RecordContext) -> list[Block]:
        u = ctx.u_v / ctx.u_scale_v
        s = ctx.p[:, 1:].sum(axis=1) / ctx.u_scale_v if ctx.p.shape[1] > 1 else u
        return [Block.make("asymmetry_um", np.column_stack([u**2, u**3, s**2, s**3, u * s]))]
