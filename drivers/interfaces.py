"""Driver protocols: the only vocabulary the rest of the product uses to talk to hardware.

Units live in names: ``_v`` volts, ``_um`` micrometres, ``_hz`` hertz, ``_s`` seconds,
``_a`` amperes, ``_f`` farads. ``daq_`` marks a voltage at the DAQ terminals (±10 V);
every other voltage is at the actuator (within the stack's rating, 0–150 V on the default bench).

This module imports nothing from ``service``: drivers know no service.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

AXES: tuple[str, ...] = ("y", "z")


class DriverError(RuntimeError):
    """A device failed or refused an operation; the message says which and why."""


class BenchLost(DriverError):
    """The process that owns the hardware (the bench engine) is gone, hung or restarting: nothing
    it was doing can be finished (service.runtime.engine.EngineUnavailable)."""


class NotSupportedError(DriverError):
    """The backend cannot do what was asked (for example point-by-point on a USB DAQ)."""


class OutputAborted(DriverError):
    """A buffered write did not play: the output was stopped (``abort``) while it waited."""


class LimitError(ValueError):
    """A request would drive the hardware outside its limits; nothing was written."""


@dataclass(frozen=True)
class DaqCapabilities:
    """What a DAQ backend can do. ``point_by_point_reason`` explains a missing mode."""

    buffered: bool
    point_by_point: bool
    ao_channels: int
    ai_channels: int
    ao_range_v: tuple[float, float]
    ai_range_v: tuple[float, float]
    resolution_bits: int
    timebase_hz: float
    max_sample_rate_hz: float
    point_by_point_reason: str | None = None
    #: samples from an AO write to the AI sample that sees its effect, beyond the sample itself
    latency_samples: int = 0

    def as_dict(self) -> dict:
        return asdict(self)


@runtime_checkable
class Daq(Protocol):
    """Analog I/O with a shared, hardware-timed sample clock.

    AO channel k drives axis k's amplifier input; AI channels carry the displacement
    gauges first (one per axis), then any monitor channels.
    """

    capabilities: DaqCapabilities

    @property
    def sample_rate_hz(self) -> float: ...

    def configure(self, sample_rate_hz: float) -> float:
        """Set the sample clock; returns the rate actually used (coerced to the timebase)."""

    def write_read(self, ao_daq_v: np.ndarray) -> np.ndarray:
        """Buffered streaming: write an (n, ao_channels) block, return the synchronised
        (n, ai_channels) block sampled on the same clock."""

    def step(self, ao_daq_v: Sequence[float]) -> np.ndarray:
        """Point-by-point: write one AO sample, return one AI sample.

        Raises NotSupportedError where ``capabilities.point_by_point`` is False."""

    def write_idle(self) -> None:
        """Drive every AO channel to 0 V now. Must work from any thread (the watchdog and the
        emergency stop call it while a loop may be stalled in another thread).

        Optional: ``begin_session()``, called by ``Bench.session`` when a run starts (the emulator
        counts its scheduled faults' ``after_s`` from there); real DAQs need not have it.
        Optional: ``abort()``, called from any thread by a stop: the running buffered write ends
        without playing the rest of its block (it returns or raises ``OutputAborted``), so the
        writing loop reaches 0 V within a fraction of a block rather than after it.
        Optional: ``temperature_c()``, the stack's temperature (°C) at each sample of the last
        ``write_read`` block, or None without a thermometer; ``Bench.run`` records it as ``temp_c``."""

    def close(self) -> None: ...


@dataclass(frozen=True)
class AmplifierStatus:
    enabled: bool
    fault: bool
    fault_reason: str | None
    output_v: float
    current_a: float
    current_limited: bool

    def as_dict(self) -> dict:
        return asdict(self)


@runtime_checkable
class Amplifier(Protocol):
    """One channel of a piezo amplifier: actuator volts = gain × DAQ volts."""

    axis: str
    gain_v_per_v: float
    output_limits_v: tuple[float, float]
    slew_limit_v_per_s: float
    current_limit_a: float
    load_capacitance_f: float

    def enable(self) -> None: ...

    def disable(self) -> None: ...

    def clear_fault(self) -> None: ...

    def status(self) -> AmplifierStatus: ...


@dataclass(frozen=True)
class SensorStatus:
    ok: bool
    saturated: bool
    reason: str | None

    def as_dict(self) -> dict:
        return asdict(self)


@runtime_checkable
class DisplacementSensor(Protocol):
    """A displacement gauge whose output voltage maps linearly to micrometres."""

    axis: str
    scale_um_per_v: float
    range_um: tuple[float, float]

    def status(self) -> SensorStatus: ...


@dataclass(frozen=True)
class AxisLimits:
    """Hard limits of one axis, all at the actuator."""

    v_min_v: float
    v_max_v: float
    slew_limit_v_per_s: float
    current_limit_a: float
    capacitance_f: float
    first_resonance_hz: float

    def max_frequency_hz(self, vpp_v: float) -> float:
        """Largest sine frequency whose peak current C·π·f·Vpp stays within the limit."""
        if vpp_v <= 0:
            return float("inf")
        f_current = self.current_limit_a / (np.pi * self.capacitance_f * vpp_v)
        f_slew = self.slew_limit_v_per_s / (np.pi * vpp_v)
        return float(min(f_current, f_slew))

    @property
    def max_rate_v_per_s(self) -> float:
        """The fastest the amplifier can move the stack's voltage (V/s): its current limit over the
        stack's capacitance (I/C), or its slew rating where that is lower."""
        return float(min(self.slew_limit_v_per_s, self.current_limit_a / self.capacitance_f))

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class BenchParts:
    """The devices a Bench composes. ``ai_channel`` maps each axis to its gauge's AI index."""

    daq: Daq
    amplifiers: dict[str, Amplifier]
    sensors: dict[str, DisplacementSensor]
    ao_channel: dict[str, int] = field(default_factory=lambda: {"y": 0, "z": 1})
    ai_channel: dict[str, int] = field(default_factory=lambda: {"y": 0, "z": 1})
    resonance_hz: dict[str, float] = field(default_factory=dict)
    backend: str = "unknown"
    config: dict = field(default_factory=dict)
    world: object | None = None  # the emulator, where there is one (for fault injection)
