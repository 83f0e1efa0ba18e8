"""GET /api/effects: the effects library, built-ins and plug-ins."""

from __future__ import annotations

from pydantic import BaseModel, Field


class EffectParameter(BaseModel):
    name: str = Field(description="a weight block, transform parameter or reported parameter the effect names")
    unit: str


class EffectEntry(BaseModel):
    name: str
    origin: str = Field(description='"builtin", "entry point NAME (module:attr)" or the plug-in file\'s path')
    kind: str = Field(description="physical | capacity")
    stage: str = Field(description="drive | additive | transform | output | capacity")
    signature: str = Field(description="what the residual shows, in words")
    rule: str = Field(description="what the data must contain to test it, in words")
    sweep: dict = Field(
        description="the /api/sweeps body (without axes) whose data tests it; a step sweep's levels as level_shares "
        "(0…1 of the drive range: a diagnosis places them on its data's range as levels_v)"
    )
    parameters: list[EffectParameter]
    inverse: str = Field(description="iterate | response | invert | none: how a feedforward undoes it")
    no_inverse: str | None = Field(default=None, description="why there is no inverse")
    emulator_bench: str | None = Field(default=None, description="the emulator's bench config that shows it")
    separated_from: list[str] = Field(description="look-alikes the diagnosis has a separating experiment for")


class FailedEffect(BaseModel):
    name: str = Field(description="the plug-in's effect name, or its file's or entry point's name")
    origin: str
    error: str


class EffectsCatalogue(BaseModel):
    effects: list[EffectEntry]
    failed: list[FailedEffect] = Field(description="plug-ins refused at start-up, each with its error")
