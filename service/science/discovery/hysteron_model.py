"""The wider rate-independent base as a model kind of its own (issue 37): ``hysterons``.

The composite model (service.science.discovery.composite) with the ``hysterons`` capacity always in
its base (service.science.effects.hysterons: a Preisach plane of general density over the play
operators, and Bouc–Wen hysterons), so that an identification can ask for it by name and discovery
starts from it. Everything else is the composite's, under the one model contract
(service.science.models.contract): ``fit`` by one bounded least-squares solve (exact, linear in
every weight), ``predict``, ``inverse`` (exact, sample by sample, for the base alone: service.science.discovery.hysteron_inverse;
with effects, the composite's),
``to_dict``/``from_dict``. Effects may be added as to any composite; the paper's static, dynamic
and GRPI models are not touched.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from service.science.data.record import finite_array
from service.science.discovery.composite import CompositeModel, as_composite
from service.science.discovery.composite_inverse import COMPOSITE_LIMITS_V
from service.science.discovery.hysteron_inverse import hysteron_inverse, invertible

#: the capacity every model of this kind carries in its base
BASE = "hysterons"


class HysteronModel(CompositeModel):
    """A composite whose base is play operators + the ``hysterons`` capacity (configuration as the
    composite's; ``effects`` always include ``hysterons``)."""

    name = "hysterons"

    def __init__(self, effects: Sequence[str] = (), n_operators: int = 10, **options):
        super().__init__([*effects, BASE], n_operators, **options)

    @classmethod
    def for_effects(cls, effects: Sequence[str], n_operators: int = 10, parent=None) -> HysteronModel:
        """Hysterons + ``effects`` (``hysteresis`` is the base and may be named), warm-started at
        ``parent``'s transforms when it has any."""
        warm = as_composite(parent).theta if parent is not None else None
        return cls([e for e in effects if e != "hysteresis"], n_operators, warm_theta=warm)

    def inverse(self, x_ref_um, *, sample_rate_hz: float | None = None, u_limits_v=None, **options) -> np.ndarray:
        """The drive (V) whose prediction follows ``x_ref_um`` (µm): the base alone is inverted exactly,
        sample by sample (service.science.discovery.hysteron_inverse); with effects, the composite's
        inverse. ``u_limits_v`` (V; None: the composite's −60…180 V)."""
        self._require_fitted()
        if not invertible(self):
            return super().inverse(x_ref_um, sample_rate_hz=sample_rate_hz, u_limits_v=u_limits_v, **options)
        limits = COMPOSITE_LIMITS_V if u_limits_v is None else u_limits_v
        return hysteron_inverse(self, finite_array("x_ref_um", x_ref_um), limits)
