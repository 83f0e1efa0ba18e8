"""Every model kind, by the name it is stored and requested under: the paper's static PI,
dynamic PI and GRPI, and the discovery composite. Callers rebuild and build models through
it and never ask which kind they hold (service.science.models.contract)."""

from __future__ import annotations

from service.science.discovery.composite import CompositeModel
from service.science.models import PAPER_MODELS

#: name -> class, every kind a stored model or an identification request may name
MODELS: dict[str, type] = {**PAPER_MODELS, CompositeModel.name: CompositeModel}


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
    return MODELS[name].for_effects(effects, n_operators, parent)
