"""The seed paper's published figures (GET /api/paper)."""

from __future__ import annotations

from pydantic import BaseModel, Field


class Table6Row(BaseModel):
    """One drive frequency of Table 6: each model's RMS error (µm)."""

    frequency_hz: float
    dynamic_pi: float
    grpi: float
    static_pi: float


class PaperGains(BaseModel):
    kp: float = Field(description="V/µm")
    ki: float = Field(description="V/(µm·s)")
    kd: float = Field(description="V·s/µm")


class TrackingCase(BaseModel):
    label: str
    body: dict = Field(description="the case as a POST /api/trajectories body (cycles left to the run)")
    max_error_um: dict[str, float] = Field(description="the paper's measured maximum error per axis (µm)")
    relative_error_pct: float = Field(
        description="the larger over the axes of the paper's max error / the case's peak-to-peak (%), the "
        "definition the service measures its runs by"
    )
    relative_error_below_pct: float = Field(description="the bound the paper's text states, one for both cases (%)")


class PaperFigures(BaseModel):
    table6_models: list[str]
    table6_rms_um: dict[str, list[Table6Row]] = Field(description="Table 6 per axis (µm)")
    static_pi_1hz_rms_um: dict[str, float]
    static_pi_weight_sum_um_per_v: dict[str, float]
    stroke_at_120v_um: dict[str, float]
    fem_first_mode_hz: dict[str, float]
    pid_gains: dict[str, PaperGains]
    tracking_cases: dict[str, TrackingCase]
