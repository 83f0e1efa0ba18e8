"""Model capacity, not a physical effect: twice as many play operators (finer thresholds)."""
from __future__ import annotations

from service.effects.base import Effect

OPERATOR_FACTOR = 2


class Operators(Effect):
    name = "operators"
    kind = "capacity"
    stage = "capacity"
    signature = ("the loop shape itself is not matched (residual repeats cycle to cycle, at all "
                 "frequencies alike): more or finer play operators; a model-capacity change, not physics")
