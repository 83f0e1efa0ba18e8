"""Every model kind, by the name it is stored and requested under: the paper's static PI,
dynamic PI and GRPI, the discovery composite, and the composite on a wider rate-independent base
(``hysterons``, issue 37). Callers rebuild and build models through
it and never ask which kind they hold (service.science.models.contract). It lives in discovery,
above the models, because the composite is one of the kinds."""

from __future__ import annotations

from service.science.discovery.composite import CompositeModel
from service.science.discovery.hysteron_model import HysteronModel
from service.science.models import PAPER_MODELS, StaticPI

#: name -> class, every kind a stored model or an identification request may name
MODELS: dict[str, type] = {**PAPER_MODELS, CompositeModel.name: CompositeModel, HysteronModel.name: HysteronModel}
#: the kind the composite is built on: an identification of it with effects beyond hysteresis
#: fits the composite of ``hysteresis + effects`` (whose base is this static PI)
COMPOSITE_BASE = StaticPI


def model_from_dict(d: dict):
    """Rebuild any registered model from its ``to_dict()``; ValueError naming ``model`` if unknown."""
    name = d.get("model")
    if name not in MODELS:
        raise ValueError(f"unknown model {name!r}; known: {', '.join(MODELS)}")
    return MODELS[name].from_dict(d)


def model_for(name: str, effects, n_operators: int = 10, parent=None):
    """The model an identification of ``hysteresis + effects`` with kind ``name`` fits
    (``parent``: the stored model it refines). ValueError naming ``model`` or ``effects``."""
    if name not in MODELS:
        raise ValueError(f"model: unknown model {name!r}; use one of {', '.join(MODELS)}")
    kind = MODELS[name]
    if kind is COMPOSITE_BASE and set(effects) - {"hysteresis"}:
        kind = CompositeModel
    return kind.for_effects(effects, n_operators, parent)
