"""The effects library: one module per physical effect plus the capacity candidates, registered here
in the order a composite model applies them; plug-ins join through ``REGISTRY.load_plugins``
(service.science.effects.registry) and appear in ``EFFECTS`` like the built-ins."""

from __future__ import annotations

from service.science.effects.asymmetry import Asymmetry
from service.science.effects.base import Effect, RecordContext
from service.science.effects.creep import Creep
from service.science.effects.cross_coupling import CrossCoupling
from service.science.effects.delay import Delay
from service.science.effects.drift import Drift
from service.science.effects.dynamics import Dynamics
from service.science.effects.gain_change import GainChange
from service.science.effects.hysterons import FineHysterons, Hysterons, SlowHysterons
from service.science.effects.line_disturbance import LineDisturbance
from service.science.effects.operators import Operators
from service.science.effects.rate_dependence import RateDependence
from service.science.effects.registry import BUILTIN, Registry
from service.science.effects.sensor_nonlinearity import SensorNonlinearity
from service.science.effects.slew_limit import SlewLimit
from service.science.effects.temperature import Temperature

#: the built-ins in application order (the drive, additive regressors, then transforms, then the gauge, capacity)
BUILTINS = (
    SlewLimit,
    RateDependence,
    Creep,
    Asymmetry,
    CrossCoupling,
    Drift,
    Temperature,
    GainChange,
    LineDisturbance,
    Delay,
    Dynamics,
    SensorNonlinearity,
    Operators,
    Hysterons,
    SlowHysterons,
    FineHysterons,
)

#: the process's registry: the built-ins, and the plug-ins once the service loads them
REGISTRY = Registry()
for _cls in BUILTINS:
    REGISTRY.register(_cls(), BUILTIN)

#: name -> effect, in application order (the registry's own dict: plug-ins appear in it once loaded)
EFFECTS: dict[str, Effect] = REGISTRY.effects


def effect_names() -> tuple[str, ...]:
    """Every name a model may list (``hysteresis`` is the base and always first), plug-ins included."""
    return ("hysteresis",) + tuple(EFFECTS)


def ordered(effects) -> list[str]:
    """Effect names (without ``hysteresis``) in registry order, duplicates removed."""
    wanted = set(effects)
    return [name for name in EFFECTS if name in wanted]


__all__ = ["EFFECTS", "REGISTRY", "Effect", "RecordContext", "effect_names", "ordered"]
