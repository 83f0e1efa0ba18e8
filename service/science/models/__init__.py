"""Hysteresis models of the PI family, their kernels and inverses (pure numpy/numba/scipy)."""
from service.science.models.base import HysteresisModel, equal_thresholds
from service.science.models.data import Series
from service.science.models.grpi import GRPI
from service.science.models.pi import DynamicPI, StaticPI

#: Model name (as stored and as used by the API) -> class.
MODEL_REGISTRY: dict[str, type[HysteresisModel]] = {cls.name: cls for cls in (StaticPI, DynamicPI, GRPI)}


def model_from_dict(d: dict) -> HysteresisModel:
    """Rebuild any registered model from its ``to_dict()``."""
    name = d.get("model")
    if name not in MODEL_REGISTRY:
        raise ValueError(f"unknown model {name!r}; known: {', '.join(MODEL_REGISTRY)}")
    return MODEL_REGISTRY[name].from_dict(d)


__all__ = ["MODEL_REGISTRY", "HysteresisModel", "Series", "StaticPI", "DynamicPI", "GRPI",
           "equal_thresholds", "model_from_dict"]
