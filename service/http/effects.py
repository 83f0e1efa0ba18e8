"""GET /api/effects: every effect discovery can add, with its origin (built-in, entry point or
plug-in file), its parameters with units and its rules, and the plug-ins refused at start-up."""

from __future__ import annotations

from fastapi import APIRouter

from service.http.schemas.effects import EffectsCatalogue
from service.science.effects import REGISTRY

router = APIRouter(tags=["effects"])


@router.get("/effects", response_model=EffectsCatalogue)
def effects() -> dict:
    """The effects library as this service loaded it (service.science.effects.registry)."""
    return REGISTRY.catalogue()
