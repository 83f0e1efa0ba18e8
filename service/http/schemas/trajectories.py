"""The tracking request: an ellipse in YOZ and its controller (feedforward, PID, ILC)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from service.http.schemas.common import Label
from service.science.control.trajectory import Ellipse


class PIDRequest(BaseModel):
    """Per-axis gains: kp V/µm, ki V/(µm·s), kd V·s/µm (paper eq. 19), derivative filter tf_s."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    kp_y: float = Field(ge=0, le=1000)
    ki_y: float = Field(default=0.0, ge=0, le=1e5)
    kd_y: float = Field(default=0.0, ge=0, le=10)
    kp_z: float = Field(ge=0, le=1000)
    ki_z: float = Field(default=0.0, ge=0, le=1e5)
    kd_z: float = Field(default=0.0, ge=0, le=10)
    tf_s: float = Field(default=1e-4, gt=0, le=1)


class ControllerRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    feedforward_model_y: str | None = None
    feedforward_model_z: str | None = None
    pid: PIDRequest | Literal["auto", "tuned", "paper"] | None = Field(
        default=None,
        description=(
            '"auto": tuned per axis on the plant identified on the bench (the feedforward model\'s largest '
            "slope, the flexure mode, the loop delay) for a 60° phase margin, 6 dB gain margin and a delay "
            'margin of 3× the loop delay; "tuned": what auto gives on the default bench; "paper": the '
            "paper's gains, refused (422 with their predicted margins) unless force; or explicit gains, "
            "refused when predicted unstable. The result's pid reports the gains and predicted margins."
        ),
    )
    #: run a PID refused by its predicted margins anyway (the divergence watch still trips it to 0 V)
    force: bool = False
    ilc: bool = False
    ilc_gain: float = Field(default=0.2, gt=0, le=1)
    ilc_harmonics: int = Field(default=20, ge=1, le=50)
    #: run a range beyond the axis's stroke anyway, commands clamped at the axis's voltage limits (the refusal becomes a warning)
    allow_saturation: bool = False


class TrajectoryRequest(BaseModel):
    """An ellipse in YOZ: ranges (min, max) µm per axis, or peak-to-peak amplitudes above min_*_um."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    shape: Literal["ellipse"] = "ellipse"
    y_range_um: tuple[float, float] | None = None
    z_range_um: tuple[float, float] | None = None
    amplitude_y_um: float | None = Field(default=None, gt=0)
    amplitude_z_um: float | None = Field(default=None, gt=0)
    min_y_um: float = Field(default=1.0, ge=0)
    min_z_um: float = Field(default=1.0, ge=0)
    inclination_deg: float = Field(default=0.0, ge=-90, le=90)
    frequency_hz: float = Field(default=100.0, gt=0, le=1000)
    cycles: int = Field(default=50, ge=1, le=10_000)
    mode: Literal["point_by_point", "buffered"] = "point_by_point"
    controller: ControllerRequest = Field(default_factory=ControllerRequest)
    name: Label | None = Field(default=None)

    @model_validator(mode="after")
    def _ranges(self):
        for ax in ("y", "z"):
            if getattr(self, f"{ax}_range_um") is None and getattr(self, f"amplitude_{ax}_um") is None:
                raise ValueError(f"give {ax}_range_um [min, max] or amplitude_{ax}_um")
        return self

    def ellipse(self) -> Ellipse:
        yr = self.y_range_um or (self.min_y_um, self.min_y_um + self.amplitude_y_um)
        zr = self.z_range_um or (self.min_z_um, self.min_z_um + self.amplitude_z_um)
        return Ellipse(
            tuple(map(float, yr)), tuple(map(float, zr)), self.inclination_deg, self.frequency_hz, self.cycles
        )


class TrackingRecipe(BaseModel):
    """The recommended path to a tracked ellipse (GET /api/trajectories/recipe)."""

    first_sweep: dict = Field(description="the POST /api/sweeps body of the first, default sweep")
    effects: list[str] = Field(description="the effects of the feedforward model identified per axis")
    controller: dict = Field(description="the controller fields to run with (beside the feedforward models)")
    why: str
