"""Hysteresis models of the PI family, their kernels and inverses, and the one model contract
(contract.py) that they and the discovery composite satisfy. Every kind:
service.science.discovery.registry."""

from service.science.models.base import HysteresisModel, equal_thresholds
from service.science.models.grpi import GRPI
from service.science.models.pi import DynamicPI, StaticPI

#: The paper's models: name (as stored and as used by the API) -> class.
PAPER_MODELS: dict[str, type[HysteresisModel]] = {cls.name: cls for cls in (StaticPI, DynamicPI, GRPI)}

__all__ = ["PAPER_MODELS", "HysteresisModel", "StaticPI", "DynamicPI", "GRPI", "equal_thresholds"]
