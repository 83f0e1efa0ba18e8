"""Emulated devices: thin driver-protocol views on one ``World``.

EmulatedDaq (NI USB-6361 class, buffered and point-by-point), EmulatedAmplifier (one channel
per axis) and EmulatedSensor (one capacitance gauge per axis). AI channels: 0 gauge Y,
1 gauge Z, 2 amplifier monitor Y, 3 amplifier monitor Z.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

import numpy as np

from drivers.emulated import kernels as K
from drivers.emulated.world import AXES, World
from drivers.interfaces import AmplifierStatus, DaqCapabilities, DriverError, LimitError, OutputAborted, SensorStatus


class EmulatedDaq:
    """Two AO, four AI, one hardware-timed clock derived from a 100 MHz timebase."""

    #: the files the stepping hook's step compiles from (a cached caller drops its cache when they change)
    stepping_sources = K.STEP_SOURCES

    def __init__(self, world: World):
        self.world = world
        daq = world.config["daq"]
        self.timebase_hz = float(daq["timebase_hz"])
        self.capabilities = DaqCapabilities(
            buffered=True,
            point_by_point=True,
            ao_channels=2,
            ai_channels=4,
            ao_range_v=(-world.range_v, world.range_v),
            ai_range_v=(-world.range_v, world.range_v),
            resolution_bits=world.bits,
            timebase_hz=self.timebase_hz,
            max_sample_rate_hz=float(daq["max_sample_rate_hz"]),
            latency_samples=world.latency,
        )
        self._closed = False
        #: one thread drives the world at a time: the loop, or a watchdog's or a stop's 0 V (the
        #: kernels release the GIL, so two writers would step the same state at once)
        self.drive_lock = threading.RLock()
        #: set by ``abort`` (a stop): buffered writes are refused until the next session begins
        self._aborted = threading.Event()
        self._thermometer = bool(world.config["ambient"].get("thermometer", False))
        self._block_temp_c: np.ndarray | None = None

    @property
    def sample_rate_hz(self) -> float:
        return self.world.sample_rate_hz

    def coerce(self, sample_rate_hz: float) -> float:
        """The rate the clock would actually run at: timebase / round(timebase / rate)."""
        rate = float(sample_rate_hz)
        if not np.isfinite(rate) or rate <= 0:
            raise LimitError(f"sample rate {sample_rate_hz!r} Hz must be a positive number")
        divisor = max(1, round(self.timebase_hz / rate))
        actual = self.timebase_hz / divisor
        if actual > self.capabilities.max_sample_rate_hz * (1 + 1e-12):
            raise LimitError(
                f"sample rate {rate:g} Hz exceeds this DAQ's {self.capabilities.max_sample_rate_hz:g} Hz "
                f"for {self.capabilities.ai_channels} AI channels"
            )
        return actual

    def temperature_c(self) -> np.ndarray | None:
        """The stack thermometer's reading (°C) at each sample of the last buffered block, or None
        where the bench has none (``[ambient] thermometer``); Bench.run records it as ``temp_c``."""
        return self._block_temp_c

    def configure(self, sample_rate_hz: float) -> float:
        self._ensure_open()
        actual = self.coerce(sample_rate_hz)
        if actual != self.world.sample_rate_hz:
            self.world.set_sample_rate(actual)
        return actual

    def _check_ao(self, ao: np.ndarray) -> None:
        if not np.all(np.isfinite(ao)):
            raise LimitError("AO data contains NaN or infinite values; nothing was written")
        peak = float(np.max(np.abs(ao))) if ao.size else 0.0
        if peak > self.world.range_v * (1 + 1e-9):
            raise LimitError(
                f"AO data reaches {peak:.4f} V, outside the ±{self.world.range_v:g} V range; nothing was written"
            )

    def write_read(self, ao_daq_v: np.ndarray) -> np.ndarray:
        """Buffered: write an (n, 2) block of DAQ volts, return the (n, 4) AI block. A scheduled
        fault (faults.py) fires at its exact sample: the block is run in two parts around it."""
        self._ensure_open()
        ao = np.asarray(ao_daq_v, dtype=np.float64)
        if ao.ndim != 2 or ao.shape[1] != 2:
            raise ValueError(f"AO block must have shape (n, 2), got {ao.shape}")
        self._check_ao(ao)
        if self._aborted.is_set():
            raise OutputAborted("the output was stopped; nothing was written")
        faults, parts, temps = self.world.faults, [], []

        def run_part(block: np.ndarray) -> None:
            with self.drive_lock:
                parts.append(self.world.run(block))
            if self._thermometer:
                temps.append(self.world.last_diag[:, K.D_TEMP_C])

        while True:
            k = faults.samples_until_due(len(ao))
            if k is None:
                break
            if k:
                run_part(ao[:k])
                ao = ao[k:]
            faults.fire_due()
        run_part(ao)
        self.world.output_log.record("block")
        if self._thermometer:  # the whole block's, also when a fault cut it in two
            self._block_temp_c = np.concatenate(temps)
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def begin_session(self) -> None:
        """A bench session starts: scheduled faults count their ``after_s`` from now; a past abort is over."""
        self._aborted.clear()
        if self.world.output_log.stage is not None:
            self.clear_watchdog()  # an expiry ended the last run (and was reported); this one may drive
        if self.world.pacer is not None:
            self.world.pacer.resume()
        self.world.faults.begin_session()

    # ------------------------------------------------------------------ the hardware watchdog
    def arm_watchdog(self, timeout_s: float) -> dict | None:
        """Arm the output stage's watchdog (0 V expiration states) with ``timeout_s`` (s); None
        without an output stage (``[emulator] output_stage``): the in-process world's outputs end
        with the engine, so no watchdog is modelled. Raises OSError/TimeoutError if it does not answer."""
        stage = self.world.output_log.stage
        if stage is None:
            return None
        armed = stage.call("arm", timeout_s=float(timeout_s))["armed_s"]
        return {"device": "emulated output stage", "timeout_s": armed, "expiration_v": 0.0}

    def pet_watchdog(self) -> str | None:
        """Pet the output stage's watchdog; its expiry in words, or None (none, or not expired)."""
        stage = self.world.output_log.stage
        return None if stage is None else stage.call("pet")["expired"]

    def clear_watchdog(self) -> None:
        """Clear an expired watchdog: the outputs follow what is written again."""
        if self.world.output_log.stage is not None:
            self.world.output_log.stage.call("clear")

    def abort(self) -> None:
        """Stop the buffered output now, from any thread (a DAQmx task stop on hardware): a write
        waiting for its slot of the real-time clock returns at once with OutputAborted instead of
        playing its block, and later writes are refused until ``begin_session``. The writer then
        drives 0 V (``write_idle``) from its own thread, so the world is never run by two threads."""
        self._aborted.set()
        if self.world.pacer is not None:
            self.world.pacer.abort()

    def step(self, ao_daq_v: Sequence[float]) -> np.ndarray:
        """Point-by-point: one AO sample in, one AI sample (4,) out, through the same kernel."""
        self._ensure_open()
        if len(ao_daq_v) != 2:
            raise ValueError(f"AO sample must have 2 values, got {len(ao_daq_v)}")
        a0, a1 = float(ao_daq_v[0]), float(ao_daq_v[1])
        if not (abs(a0) <= self.world.range_v * (1 + 1e-9) and abs(a1) <= self.world.range_v * (1 + 1e-9)):
            raise LimitError(
                f"AO sample ({a0}, {a1}) V is outside ±{self.world.range_v:g} V or not finite; nothing was written"
            )
        with self.drive_lock:
            return self.world.step(a0, a1)

    def stepping_hook(self):
        """Optional compiled point-by-point hook: ``(step_fn, args, take_noise)``. A compiled caller
        steps the world with ``step_fn(*args, ao0, ao1, noise, kn, out, ko, diag)`` using rows of
        ``take_noise(n) -> (noise, first_row)``, holding ``drive_lock`` while it steps; the same
        kernel as ``step``. None when closed."""
        if self._closed or not self.capabilities.point_by_point:
            return None
        step_fn, args = self.world.kernel_state()
        world = self.world

        def take_noise(n: int):
            """Once per period: log the output, fire the faults due within the next n samples, and
            start the gauges' saturation count afresh (per block, as ``run`` and ``step`` do; a
            count left from an earlier block, e.g. ringing after a trip, is not this period's)."""
            world.sa[:, K.S_SATN] = 0.0
            if n:
                world.output_log.record("period")
            if world.faults.samples_until_due(n) is not None:
                world.faults.fire_due()
            return world.take_noise(n)

        return step_fn, args, take_noise

    def timing(self) -> dict:
        """Real-time pacing counters (``realtime``, ``periods``, ``overruns``, ``max_late_ms``);
        ``{"realtime": False}`` when the emulator runs as fast as it can."""
        pacer = self.world.pacer
        return pacer.counters() if pacer is not None else {"realtime": False}

    def write_idle(self) -> None:
        """AO to 0 V, then let the world run idle until the amplifier outputs are below 10 mV."""
        if self._closed:
            return
        with self.drive_lock:
            t0 = self.world.time_s
            self.world.idle()
        self.world.faults.idle_written()
        self.world.output_log.record("idle", zero_from_t_s=round(t0, 6))

    def close(self) -> None:
        if not self._closed:
            with self.drive_lock:
                self.world.idle()
            self.world.faults.idle_written()
            self.world.output_log.record("close")
            self.world.output_log.close()
            self._closed = True

    def _ensure_open(self) -> None:
        if self._closed:
            raise DriverError("the emulated DAQ is closed")


class EmulatedAmplifier:
    """One amplifier channel. Starts enabled; a latched fault drives the output to 0 V."""

    def __init__(self, world: World, axis: str):
        self.world = world
        self.axis = axis
        self._a = world.axis_index(axis)
        amp = world.config["axes"][axis]["amplifier"]
        self.gain_v_per_v = float(amp["gain_v_per_v"])
        self.output_limits_v = (float(amp["output_min_v"]), float(amp["output_max_v"]))
        self.slew_limit_v_per_s = float(amp["slew_limit_v_per_s"])
        self.current_limit_a = float(amp["current_limit_a"])
        self.load_capacitance_f = float(amp["load_capacitance_f"])

    def enable(self) -> None:
        self.world.sa[self._a, K.S_ENABLED] = 1.0

    def disable(self) -> None:
        self.world.sa[self._a, K.S_ENABLED] = 0.0

    def clear_fault(self) -> None:
        self.world.clear_amplifier_fault(self._a)

    def status(self) -> AmplifierStatus:
        sa = self.world.sa[self._a]
        fault = bool(sa[K.S_FAULT] > 0.5)
        reason = None
        if fault:
            reason = (
                f"over-current: {sa[K.S_FAULT_I] * 1e3:.0f} mA demanded (limit {self.current_limit_a * 1e3:.0f} mA) "
                f"for {sa[K.S_FAULT_T] * 1e3:.1f} ms"
            )
            reason += self.world.injected_note("amplifier_overcurrent", self.axis)
        return AmplifierStatus(
            enabled=bool(sa[K.S_ENABLED] > 0.5),
            fault=fault,
            fault_reason=reason,
            output_v=float(sa[K.S_VP]),
            current_a=float(sa[K.S_IA]),
            current_limited=bool(sa[K.S_CLIM] > 0.5),
        )


class EmulatedSensor:
    """A capacitance gauge: ±10 V over ±range, linear scale_um_per_v."""

    def __init__(self, world: World, axis: str):
        self.world = world
        self.axis = axis
        self._a = world.axis_index(axis)
        self.scale_um_per_v = float(world.config["axes"][axis]["gauge"]["scale_um_per_v"])
        span = world.range_v * self.scale_um_per_v
        self.range_um = (-span, span)

    def status(self) -> SensorStatus:
        sa = self.world.sa[self._a]
        if sa[K.S_DROP] > 0.5:
            why = self.world.injected_note("sensor_dropout", self.axis) or " (signal lost)"
            return SensorStatus(
                ok=False, saturated=False, reason=f"gauge {self.axis}: dropout{why}, output stuck at 0 V"
            )
        if sa[K.S_SAT] > 0.5 or sa[K.S_SATN] > 0:
            v = sa[K.S_GV]
            return SensorStatus(
                ok=False,
                saturated=True,
                reason=f"gauge {self.axis}: saturated{self.world.injected_note('sensor_saturation', self.axis)} "
                f"({int(sa[K.S_SATN])} samples at ±{self.world.range_v:g} V, "
                f"last {v:+.2f} V): target outside ±{self.range_um[1]:g} µm",
            )
        return SensorStatus(ok=True, saturated=False, reason=None)


def build_devices(world: World):
    daq = EmulatedDaq(world)
    amps = {ax: EmulatedAmplifier(world, ax) for ax in AXES}
    sensors = {ax: EmulatedSensor(world, ax) for ax in AXES}
    return daq, amps, sensors
