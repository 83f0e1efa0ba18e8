"""The effects library: one module per physical effect plus the ``operators`` capacity
candidate, registered here in the order a composite model applies them."""

from __future__ import annotations

from service.science.effects.asymmetry import Asymmetry
from service.science.effects.base import Effect, RecordContext
from service.science.effects.creep import Creep
from service.science.effects.cross_coupling import CrossCoupling
from service.science.effects.delay import Delay
from service.science.effects.drift import Drift
from service.science.effects.dynamics import Dynamics
from service.science.effects.hysterons import Hysterons
from service.science.effects.operators import Operators
from service.science.effects.rate_dependence import RateDependence
from service.science.effects.sensor_nonlinearity import SensorNonlinearity
from service.science.effects.temperature import Temperature

#: name -> effect, in application order (additive regressors, then transforms, then the gauge)
EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        RateDependence(),
        Creep(),
        Asymmetry(),
        CrossCoupling(),
        Drift(),
        Temperature(),
        Delay(),
        Dynamics(),
        SensorNonlinearity(),
        Operators(),
        Hysterons(),
    )
}

#: every name a model may list (``hysteresis`` is the base and always first)
EFFECT_NAMES = ("hysteresis",) + tuple(EFFECTS)


def ordered(effects) -> list[str]:
    """Effect names (without ``hysteresis``) in registry order, duplicates removed."""
    wanted = set(effects)
    return [name for name in EFFECTS if name in wanted]


__all__ = ["EFFECTS", "EFFECT_NAMES", "Effect", "RecordContext", "ordered"]
