"""Admin: fault injection on the emulated bench and API tokens."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from drivers.emulated.faults import KINDS


class FaultRequest(BaseModel):
    """One fault: its kind, the axis (sensor and amplifier faults) and when, in seconds."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    fault: str = Field(description=f"one of {', '.join(KINDS)}")
    axis: str | None = Field(default=None, description="y or z, for sensor_* and amplifier_* faults")
    after_s: float = Field(default=0.0, ge=0, le=1e6, description="emulated seconds into the bench session")


class Fault(BaseModel):
    """A scheduled fault: ``state`` armed | fired; ``fired_at_s`` the session time it fired at,
    ``world_t_s`` the emulator's clock then (s)."""

    id: int
    kind: str
    axis: str | None
    after_s: float
    source: str = Field(description="api | config")
    state: str
    fired_at_s: float | None
    world_t_s: float | None


class Faults(BaseModel):
    faults: list[Fault]
    kinds: list[str]
    transports: list[str] = Field(description="wire transports this bench has (serial, can)")


class FaultsCleared(BaseModel):
    cleared: int = Field(description="how many faults were removed")
    notes: list[str] = Field(description="what a clear cannot undo")
    output_v: dict[str, float]


class TokenRequest(BaseModel):
    name: str = Field(min_length=1, max_length=200, description="who or what uses the token")
    scope: Literal["read", "operate", "admin"] = Field("read", description="read ⊂ operate ⊂ admin")


class Token(BaseModel):
    """A token's record (never its secret): ``scopes`` are the scopes it grants."""

    id: str
    name: str
    scope: str
    origin: str = Field(description="cli | api | bootstrap")
    revoked: bool
    created_at: str
    revoked_at: str | None
    scopes: list[str]


class NewToken(Token):
    """The new token's plaintext is in ``token``, in this answer only (it is stored hashed)."""

    token: str
