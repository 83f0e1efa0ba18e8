"""Cross-coupling: this axis moves with the other axis (parasitic flexure coupling): the other
axis's drive through its own play operators and linear term (µm/V, free sign)."""
from __future__ import annotations

import numpy as np

from service.effects.base import Effect, RecordContext
from service.identification.lsq import Block


class CrossCoupling(Effect):
    name = "cross_coupling"
    signature = "this axis's residual follows the other axis's drive while this axis's own drive does not explain it"

    def blocks(self, ctx: RecordContext) -> list[Block]:
        if ctx.p_other is None:
            cols = np.zeros((ctx.n, 2))
        else:
            cols = np.column_stack([ctx.p_other[:, 0], ctx.p_other[:, 1:].sum(axis=1)])
        return [Block.make("coupling_um_per_v", cols)]
