"""Health, the bench's state and live signals, the emergency stop and the reset."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field

from service.http.schemas.common import OPEN


class Health(BaseModel):
    """Liveness: the software version, the bench backend and the store's database."""

    status: str = Field(description='"ok", or "degraded" (503) while the bench engine is absent or restarting')
    engine: str = Field(default="running", description="the bench engine: running | restarting | absent")
    reason: str | None = Field(default=None, description="why the engine is absent or restarting")
    latched_fault: str | None = Field(
        default=None, description='"engine restarted: …" until POST /api/bench/reset clears it'
    )
    version: str
    backend: str
    store: str = Field(description="sqlite | postgresql")
    uptime_s: float


class AmplifierState(BaseModel):
    model_config = OPEN
    gain_v_per_v: float
    enabled: bool
    fault: bool
    fault_reason: str | None
    output_v: float
    current_a: float
    current_limited: bool


class SensorState(BaseModel):
    model_config = OPEN
    scale_um_per_v: float
    range_um: list[float]
    ok: bool
    saturated: bool
    reason: str | None


class AxisLimits(BaseModel):
    """The hard limits of one axis: actuator volts, amperes into the stack, V/s, hertz."""

    model_config = OPEN
    v_min_v: float
    v_max_v: float
    current_limit_a: float
    slew_limit_v_per_s: float
    capacitance_f: float
    first_resonance_hz: float | None
    max_frequency_hz_at_full_range: float | None = Field(
        description="the largest sine frequency (Hz) at the full voltage range: current, slew and 0.5 × the first resonance"
    )


class SafetyState(BaseModel):
    model_config = OPEN
    watchdog_periods: float
    watchdog_min_s: float
    watchdog_poll_s: float
    stop_wait_s: float
    unread_limit_s: float = Field(
        description="a run whose samples the service has not taken for this long stops at 0 V (s)"
    )
    watchdog_last_trip: dict[str, Any] | None
    stop_requested: bool
    running: bool


class Modes(BaseModel):
    buffered: bool
    point_by_point: bool
    point_by_point_reason: str | None


class BenchState(BaseModel):
    """The bench's devices, their present state and its hard limits, per axis."""

    model_config = OPEN
    backend: str
    axes: list[str]
    sample_rate_hz: float | None
    daq: dict[str, Any] = Field(description="the DAQ's capabilities (channels, ranges, resolution, timebase)")
    amplifiers: dict[str, AmplifierState]
    sensors: dict[str, SensorState]
    limits: dict[str, AxisLimits]
    safety: SafetyState
    modes: Modes
    timing: dict[str, Any] = Field(
        description="real-time pacing of an emulated DAQ: realtime, periods, overruns, max_late_ms"
    )
    engine: dict[str, Any] | None = Field(
        default=None,
        description="the bench engine process, when separate: process, pid, stop_port (its own emergency-stop port)",
    )
    bench_id: str = Field(description="this service's bench (a lab's id; the stop port takes it as ?bench_id=)")
    running_job_id: str | None


class LiveSignals(BaseModel):
    """Decimated live samples since the cursor: ``t_s`` restarts at 0 s with every run (``runs``
    numbers each sample's run); per axis ``u_<axis>_v`` and ``x_<axis>_um`` (null: not measured)."""

    model_config = OPEN
    cursor: int = Field(description="pass as ?since= on the next call")
    first: int
    run: int
    label: str | None
    rate_hz: float | None
    stride: int
    dropped: int
    t_s: list[float]
    runs: list[int]
    u_y_v: list[float | None] | None = None
    x_y_um: list[float | None] | None = None
    u_z_v: list[float | None] | None = None
    x_z_um: list[float | None] | None = None
    axes: list[str]
    running_job_id: str | None


class EmergencyStop(BaseModel):
    """Outputs at 0 V; the job that owned the bench and those queued behind it cancelled."""

    stopped: bool
    door: str = Field(
        description="'service route' here; 'stop port' when pressed on the engine's own port "
        "(GET /api/bench: engine.stop_port), which answers with the same fields"
    )
    cancelled_job_id: str | None
    cancelled_queued_job_ids: list[str]
    loop_answered: bool | None = Field(description="a running loop wrote the 0 V itself")
    output_v: dict[str, float]
    zero_after_request_ms: float | None = Field(description="the engine's time from the stop to the 0 V write")
    zero_monotonic_s: float | None
    engine_note: str | None = Field(
        default=None,
        description="set when there was no bench engine to stop: what was done about the outputs instead",
    )


class FaultsReset(BaseModel):
    """What a reset cleared and what remains (a lost sensor is not mended by a reset)."""

    cleared: list[str]
    remaining: str | None
    output_v: dict[str, float]
