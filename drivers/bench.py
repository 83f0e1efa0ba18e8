"""The Bench: composes a DAQ, amplifiers and gauges per axis, converts units and enforces limits.

Chain per axis: actuator volts ``u_v`` → DAQ volts (÷ amplifier gain) → DAQ AO → amplifier
→ piezo → gauge → DAQ AI volts → micrometres (× gauge scale).

Safety, in order of defence:
1. ``check_waveform`` refuses a whole plan that leaves 0–120 V, or whose rate of change
   exceeds the slew limit or the amplifier's current limit into the stack capacitance.
2. Every command that reaches the DAQ is clamped to 0–120 V and rate-limited.
3. Every run, stop, close or failure ends with the DAQ output at 0 V.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from drivers.interfaces import AxisLimits, BenchParts, DriverError, LimitError, NotSupportedError
from drivers.live import LiveMonitor

ACTUATOR_V_MIN = 0.0
ACTUATOR_V_MAX = 120.0
# A sampled waveform's finite-difference slope overshoots the analytic one by rounding
# and quantisation; allow this relative margin before calling it a limit violation.
_RATE_CHECK_MARGIN = 1.02
# A non-resonant device works below its first resonance; a sine above this fraction of it
# rings the flexure (and its harmonics sit on the mode), so it is refused.
RESONANCE_FRACTION = 0.5


class RunInterrupted(DriverError):
    """A run stopped early (cancel, device fault, sensor loss). ``record`` holds the data so far."""

    def __init__(self, reason: str, record: "BenchRecord"):
        super().__init__(reason)
        self.reason = reason
        self.record = record


@dataclass
class BenchRecord:
    """What a buffered run measured. Arrays are per axis, one value per sample."""

    sample_rate_hz: float
    u_cmd_v: dict[str, np.ndarray]
    x_um: dict[str, np.ndarray]
    partial: bool = False
    reason: str | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def samples(self) -> int:
        return len(next(iter(self.x_um.values()))) if self.x_um else 0

    @property
    def t_s(self) -> np.ndarray:
        return np.arange(self.samples) / self.sample_rate_hz


class Bench:
    """A two-axis piezo bench behind driver interfaces. Thread-safe: one run at a time."""

    def __init__(self, parts: BenchParts, v_min_v: float = ACTUATOR_V_MIN, v_max_v: float = ACTUATOR_V_MAX):
        if v_min_v < ACTUATOR_V_MIN or v_max_v > ACTUATOR_V_MAX or v_min_v >= v_max_v:
            raise LimitError(f"actuator range {v_min_v}–{v_max_v} V is outside the stack's 0–120 V")
        self.parts = parts
        self.axes: tuple[str, ...] = tuple(sorted(parts.amplifiers))
        self.limits: dict[str, AxisLimits] = {}
        for axis, amp in parts.amplifiers.items():
            self.limits[axis] = AxisLimits(
                v_min_v=max(v_min_v, amp.output_limits_v[0]),
                v_max_v=min(v_max_v, amp.output_limits_v[1]),
                slew_limit_v_per_s=amp.slew_limit_v_per_s,
                current_limit_a=amp.current_limit_a,
                capacitance_f=amp.load_capacitance_f,
                first_resonance_hz=parts.resonance_hz.get(axis, float("nan")),
            )
        self._lock = threading.RLock()
        self._stop_requested = threading.Event()
        self._last_u_v = {axis: 0.0 for axis in self.axes}
        self._closed = False
        #: decimated live signals of whatever the bench streams (see drivers/live.py)
        self.live = LiveMonitor(self.axes)

    # ------------------------------------------------------------------ limits
    def max_frequency_hz(self, axis: str, vpp_v: float) -> float:
        """Largest sine frequency at ``vpp_v`` that the amplifier can drive into the stack."""
        return self.limits[self._axis(axis)].max_frequency_hz(vpp_v)

    def check_sine(self, axis: str, vpp_v: float, frequency_hz: float) -> None:
        """Refuse a sine whose peak current or slew rate exceeds the amplifier's limits, or whose
        frequency comes within reach of the axis's first resonance."""
        lim = self.limits[self._axis(axis)]
        need_a = np.pi * frequency_hz * vpp_v * lim.capacitance_f
        if need_a > lim.current_limit_a:
            raise LimitError(
                f"{vpp_v:g} Vpp at {frequency_hz:g} Hz needs {need_a * 1e3:.0f} mA; the amplifier's "
                f"limit is {lim.current_limit_a * 1e3:.0f} mA (largest frequency at this amplitude: "
                f"{lim.max_frequency_hz(vpp_v):.1f} Hz)")
        slew = np.pi * frequency_hz * vpp_v
        if slew > lim.slew_limit_v_per_s:
            raise LimitError(
                f"{vpp_v:g} Vpp at {frequency_hz:g} Hz slews at {slew / 1e3:.1f} V/ms; the amplifier's "
                f"limit is {lim.slew_limit_v_per_s / 1e3:.1f} V/ms")
        if np.isfinite(lim.first_resonance_hz) and frequency_hz > RESONANCE_FRACTION * lim.first_resonance_hz:
            raise LimitError(
                f"{frequency_hz:g} Hz is above {RESONANCE_FRACTION:g} × the {axis} axis's first resonance "
                f"({lim.first_resonance_hz:g} Hz); a non-resonant drive must stay below "
                f"{RESONANCE_FRACTION * lim.first_resonance_hz:.1f} Hz")

    def check_waveform(self, u_v: Mapping[str, np.ndarray], sample_rate_hz: float) -> None:
        """Refuse a planned waveform that would leave the limits. Raises LimitError saying why."""
        if sample_rate_hz <= 0 or not np.isfinite(sample_rate_hz):
            raise LimitError(f"sample rate {sample_rate_hz} Hz must be a positive number")
        for axis, u in u_v.items():
            lim = self.limits[self._axis(axis)]
            u = np.asarray(u, dtype=float)
            if u.ndim != 1 or len(u) == 0:
                raise LimitError(f"u_{axis} must be a non-empty 1-D array of volts")
            if not np.all(np.isfinite(u)):
                raise LimitError(f"u_{axis} contains NaN or infinite values")
            if u.max() > lim.v_max_v or u.min() < lim.v_min_v:
                raise LimitError(
                    f"u_{axis} spans {u.min():.1f}–{u.max():.1f} V; the actuator limit is "
                    f"{lim.v_min_v:g}–{lim.v_max_v:g} V")
            if len(u) > 1:
                rate = float(np.max(np.abs(np.diff(u)))) * sample_rate_hz
                need_a = rate * lim.capacitance_f
                if need_a > lim.current_limit_a * _RATE_CHECK_MARGIN:
                    raise LimitError(
                        f"u_{axis} changes at up to {rate / 1e3:.1f} V/ms, which needs {need_a * 1e3:.0f} mA "
                        f"into {lim.capacitance_f * 1e6:.2f} µF; the amplifier's limit is "
                        f"{lim.current_limit_a * 1e3:.0f} mA")
                if rate > lim.slew_limit_v_per_s * _RATE_CHECK_MARGIN:
                    raise LimitError(
                        f"u_{axis} changes at up to {rate / 1e3:.1f} V/ms; the amplifier's slew limit is "
                        f"{lim.slew_limit_v_per_s / 1e3:.1f} V/ms")

    def clamp(self, axis: str, u_v: float, previous_v: float, dt_s: float) -> float:
        """Clamp one command to the voltage range and to the largest step the limits allow."""
        lim = self.limits[axis]
        max_step = dt_s * min(lim.slew_limit_v_per_s, lim.current_limit_a / lim.capacitance_f)
        u = min(max(u_v, previous_v - max_step), previous_v + max_step)
        return min(max(u, lim.v_min_v), lim.v_max_v)

    def clamp_block(self, axis: str, u_v: np.ndarray, previous_v: float, sample_rate_hz: float) -> np.ndarray:
        """Vector form of ``clamp`` for a block of commands (sequential because of the rate limit)."""
        lim = self.limits[axis]
        u = np.clip(np.nan_to_num(np.asarray(u_v, dtype=float), nan=0.0), lim.v_min_v, lim.v_max_v)
        max_step = min(lim.slew_limit_v_per_s, lim.current_limit_a / lim.capacitance_f) / sample_rate_hz
        steps = np.diff(np.concatenate(([previous_v], u)))
        if np.all(np.abs(steps) <= max_step):
            return u
        out = np.empty_like(u)
        prev = previous_v
        for k, target in enumerate(u):  # rare path: only when a block violates the rate limit
            prev = min(max(target, prev - max_step), prev + max_step)
            out[k] = prev
        return out

    # ------------------------------------------------------------------ running
    def configure(self, sample_rate_hz: float) -> float:
        """Set the sample clock; returns the coerced rate the DAQ will use."""
        with self._lock:
            return self.parts.daq.configure(sample_rate_hz)

    @property
    def sample_rate_hz(self) -> float:
        return self.parts.daq.sample_rate_hz

    @property
    def supports_point_by_point(self) -> bool:
        return self.parts.daq.capabilities.point_by_point

    def request_stop(self) -> None:
        """Ask the running job to stop at its next block or sample; the output then goes to 0 V."""
        self._stop_requested.set()

    def run(self, u_v: Mapping[str, np.ndarray], sample_rate_hz: float, *, block_samples: int = 2000,
            on_block: Callable[[BenchRecord, float], None] | None = None,
            should_stop: Callable[[], bool] | None = None) -> BenchRecord:
        """Stream a planned waveform through the bench in buffered blocks and return the record.

        ``u_v`` maps axis → actuator volts; axes left out are held at 0 V. ``on_block`` gets the
        record so far and the fraction done; ``should_stop`` is polled between blocks. A stop, a
        device fault or sensor saturation raises RunInterrupted carrying the partial record. The
        output is at 0 V when this returns or raises.
        """
        self._ensure_open()
        self.check_waveform(u_v, sample_rate_hz)
        lengths = {len(np.asarray(u)) for u in u_v.values()}
        if len(lengths) != 1:
            raise LimitError(f"all axes need the same number of samples, got {sorted(lengths)}")
        n = lengths.pop()
        with self._lock:
            self._stop_requested.clear()
            actual = self.parts.daq.configure(sample_rate_hz)
            if abs(actual - sample_rate_hz) > 1e-9 * sample_rate_hz:
                raise LimitError(f"sample rate {sample_rate_hz} Hz is not a divisor of the DAQ timebase; "
                                 f"use {actual} Hz")
            daq = self.parts.daq
            n_ao = daq.capabilities.ao_channels
            commands = {axis: np.asarray(u_v.get(axis, np.zeros(n)), dtype=float) for axis in self.axes}
            chunks_u: dict[str, list[np.ndarray]] = {axis: [] for axis in self.axes}
            chunks_ai: list[np.ndarray] = []
            previous = {axis: 0.0 for axis in self.axes}
            self.live.begin(actual, "buffered run")
            try:
                for start in range(0, n, block_samples):
                    stop = min(start + block_samples, n)
                    ao = np.zeros((stop - start, n_ao))
                    for axis in self.axes:
                        block = self.clamp_block(axis, commands[axis][start:stop], previous[axis], actual)
                        previous[axis] = float(block[-1])
                        chunks_u[axis].append(block)
                        ao[:, self.parts.ao_channel[axis]] = block / self.parts.amplifiers[axis].gain_v_per_v
                    try:
                        chunks_ai.append(daq.write_read(ao))
                    except RunInterrupted:
                        raise
                    except DriverError as exc:  # a transport failed mid-run: keep the blocks measured so far
                        for axis in self.axes:
                            chunks_u[axis].pop()
                        record = self._record(chunks_u, chunks_ai, actual)
                        record.partial, record.reason = True, f"daq: {exc}"
                        raise RunInterrupted(record.reason, record) from exc
                    self.live.push({a: chunks_u[a][-1] for a in self.axes}, self._x_um(chunks_ai[-1]))
                    fault = self.fault_reason()
                    record = self._record(chunks_u, chunks_ai, actual)
                    if fault:
                        record.partial, record.reason = True, fault
                        raise RunInterrupted(fault, record)
                    if on_block is not None:
                        on_block(record, stop / n)
                    if stop < n and (self._stop_requested.is_set() or (should_stop and should_stop())):
                        record.partial, record.reason = True, "stopped on request"
                        raise RunInterrupted("stopped on request", record)
                return self._record(chunks_u, chunks_ai, actual)
            finally:
                self._to_zero()

    def step(self, u_v: Mapping[str, float]) -> dict[str, float]:
        """Point-by-point: apply one clamped sample per axis and return x_um per axis."""
        self._ensure_open()
        daq = self.parts.daq
        if not daq.capabilities.point_by_point:
            raise NotSupportedError(daq.capabilities.point_by_point_reason or "this DAQ has no point-by-point mode")
        dt = 1.0 / daq.sample_rate_hz
        ao = [0.0] * daq.capabilities.ao_channels
        for axis in self.axes:
            u = self.clamp(axis, float(u_v.get(axis, 0.0)), self._last_u_v[axis], dt)
            self._last_u_v[axis] = u
            ao[self.parts.ao_channel[axis]] = u / self.parts.amplifiers[axis].gain_v_per_v
        try:
            ai = daq.step(ao)
        except Exception:
            self._to_zero()
            raise
        return {axis: float(ai[self.parts.ai_channel[axis]]) * self.parts.sensors[axis].scale_um_per_v
                for axis in self.axes}

    def stop(self) -> None:
        """Emergency stop: request any run to end and drive the output to 0 V now."""
        self._stop_requested.set()
        self._to_zero()

    def close(self) -> None:
        if self._closed:
            return
        try:
            self._to_zero()
        finally:
            self._closed = True
            self.parts.daq.close()

    def __enter__(self) -> "Bench":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ state
    def output_v(self) -> dict[str, float]:
        """The amplifier output per axis, in actuator volts."""
        return {axis: self.parts.amplifiers[axis].status().output_v for axis in self.axes}

    def describe(self) -> dict:
        """Backend, axes, device states and limits, for GET /api/bench."""
        daq = self.parts.daq
        return {
            "backend": self.parts.backend,
            "axes": list(self.axes),
            "sample_rate_hz": daq.sample_rate_hz,
            "daq": daq.capabilities.as_dict(),
            "amplifiers": {a: {"gain_v_per_v": amp.gain_v_per_v, **amp.status().as_dict()}
                           for a, amp in self.parts.amplifiers.items()},
            "sensors": {a: {"scale_um_per_v": s.scale_um_per_v, "range_um": list(s.range_um),
                            **s.status().as_dict()} for a, s in self.parts.sensors.items()},
            "limits": {a: {**lim.as_dict(), "max_frequency_hz_at_full_range":
                           lim.max_frequency_hz(lim.v_max_v - lim.v_min_v)} for a, lim in self.limits.items()},
            "modes": {"buffered": daq.capabilities.buffered, "point_by_point": daq.capabilities.point_by_point,
                      "point_by_point_reason": daq.capabilities.point_by_point_reason},
            # real-time pacing of an emulated DAQ: periods paced and overruns (a real DAQ has none)
            "timing": daq.timing() if callable(getattr(daq, "timing", None)) else {"realtime": False},
        }

    def _record(self, chunks_u, chunks_ai, rate) -> BenchRecord:
        ai = np.concatenate(chunks_ai) if chunks_ai else np.zeros((0, self.parts.daq.capabilities.ai_channels))
        x = self._x_um(ai)
        u = {a: np.concatenate(chunks_u[a]) if chunks_u[a] else np.zeros(0) for a in self.axes}
        return BenchRecord(sample_rate_hz=rate, u_cmd_v=u, x_um=x)

    def _x_um(self, ai: np.ndarray) -> dict[str, np.ndarray]:
        """DAQ input volts (samples × channels) → micrometres per axis."""
        return {a: ai[:, self.parts.ai_channel[a]] * self.parts.sensors[a].scale_um_per_v for a in self.axes}

    def fault_reason(self) -> str | None:
        """The first amplifier fault or sensor loss, in words, or None when every part is healthy."""
        for axis in self.axes:
            amp = self.parts.amplifiers[axis].status()
            if amp.fault:
                return f"amplifier {axis}: {amp.fault_reason or 'fault'}"
            sensor = self.parts.sensors[axis].status()
            if not sensor.ok:
                return f"sensor {axis}: {sensor.reason or 'not ok'}"
        return None

    def _to_zero(self) -> None:
        self.parts.daq.write_idle()
        for axis in self.axes:
            self._last_u_v[axis] = 0.0

    def _ensure_open(self) -> None:
        if self._closed:
            raise DriverError("the bench is closed")

    def _axis(self, axis: str) -> str:
        if axis not in self.limits:
            raise LimitError(f"unknown axis {axis!r}; this bench has {', '.join(self.axes)}")
        return axis
