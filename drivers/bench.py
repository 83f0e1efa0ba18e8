"""The Bench: composes a DAQ, amplifiers and gauges per axis, converts units and enforces limits.

Chain per axis: actuator volts ``u_v`` → DAQ volts (÷ amplifier gain) → DAQ AO → amplifier
→ piezo → gauge → DAQ AI volts → micrometres (× gauge scale).

Safety, in order of defence:
1. ``check_waveform`` refuses a whole plan that leaves the axis's voltage range (the stack's
   rating from the bench config, within the amplifier's output: 0–150 V on the default bench), or
   whose rate of change exceeds the slew limit or the amplifier's current limit into the stack
   capacitance.
2. Every command that reaches the DAQ is clamped to that range and rate-limited.
3. Every run happens inside ``session()``, which guarantees 0 V on exit, arms the watchdog
   (drivers/watchdog.py: 0 V when no sample is written for N periods) and carries the stop
   flag that ``stop()`` raises; loops check it every block (buffered) or every ≤ 50 samples
   (the compiled point-by-point runner), so a stop pre-empts a run within one control period.
4. Every run, stop, close or failure ends with the DAQ output at 0 V.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager

import numpy as np

from drivers.interfaces import AxisLimits, BenchParts, DriverError, LimitError, NotSupportedError
from drivers.limits import LimitsMixin, highest_sine_hz, stack_rating_v
from drivers.live import LiveMonitor
from drivers.record import Acquired, BenchRecord
from drivers.watchdog import SafetyConfig, Watchdog

STOPPED_ON_REQUEST = "stopped on request"

#: samples per buffered block of ``Bench.run`` (one control period of a sweep)
RUN_BLOCK_SAMPLES = 2000


class BenchBusy(DriverError):
    """The bench is owned by a run; the request needs it idle."""


class BenchSession:
    """What a loop holds while it owns the bench: ``stop_flag`` (uint8[1], non-zero = stop; compiled
    loops poll it), ``feed(samples)`` for the watchdog and ``interrupted()``: the reason to stop now."""

    def __init__(self, bench: Bench):
        self.bench = bench
        self.stop_flag = bench._stop_flag
        self.feed = bench.watchdog.feed

    def interrupted(self) -> str | None:
        """The watchdog trip or the stop request, in words, or None to carry on."""
        return self.bench.interrupt_reason()


class Bench(LimitsMixin):
    """A two-axis piezo bench behind driver interfaces. Thread-safe: one run at a time."""

    def __init__(self, parts: BenchParts, v_min_v: float | None = None, v_max_v: float | None = None):
        """``v_min_v``/``v_max_v`` (V) narrow the range further; they may not widen the stack's rating."""
        self.parts = parts
        self.axes: tuple[str, ...] = tuple(sorted(parts.amplifiers))
        self.limits: dict[str, AxisLimits] = {}
        for axis, amp in parts.amplifiers.items():
            rated_min_v, rated_max_v = stack_rating_v(parts.config, axis)
            lo = rated_min_v if v_min_v is None else v_min_v
            hi = rated_max_v if v_max_v is None else v_max_v
            if lo < rated_min_v or hi > rated_max_v or lo >= hi:
                raise LimitError(
                    f"actuator range {lo:g}–{hi:g} V is outside the {axis} stack's rating "
                    f"{rated_min_v:g}–{rated_max_v:g} V"
                )
            self.limits[axis] = AxisLimits(
                v_min_v=max(lo, amp.output_limits_v[0]),
                v_max_v=min(hi, amp.output_limits_v[1]),
                slew_limit_v_per_s=amp.slew_limit_v_per_s,
                current_limit_a=amp.current_limit_a,
                capacitance_f=amp.load_capacitance_f,
                first_resonance_hz=parts.resonance_hz.get(axis, float("nan")),
            )
        self._lock = threading.RLock()
        self._stop_flag = np.zeros(1, dtype=np.uint8)  # shared with compiled loops
        self._stop_reason: str | None = None
        self._idle = threading.Event()  # set while no session runs
        self._plans = 0  # plans running (plan_scope): a stop latches for them
        self._idle.set()
        self.tripped: str | None = None  # the watchdog's reason, latched for the session
        self._last_u_v = {axis: 0.0 for axis in self.axes}
        #: time.monotonic() (s) when the DAQ output last reached 0 V (a write_idle returned)
        self.last_zero_monotonic_s: float | None = None
        self.last_stop: dict | None = None
        self._closed = False
        self.safety = SafetyConfig.from_config(parts.config.get("safety"))
        self.watchdog = Watchdog(parts.daq, self.safety, on_trip=self._on_watchdog_trip)
        #: decimated live signals of whatever the bench streams (see drivers/live.py)
        self.live = LiveMonitor(self.axes)

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

    def request_stop(self, reason: str = STOPPED_ON_REQUEST) -> None:
        """Ask the running loop to stop now: the flag its compiled loops poll every ≤ 50 samples, and
        the DAQ's ``abort`` (where it has one), which ends a buffered block that is waiting for its
        slot; the loop then writes 0 V from its own thread."""
        if self._stop_reason is None or reason != STOPPED_ON_REQUEST:
            self._stop_reason = reason
        self._stop_flag[0] = 1
        abort = getattr(self.parts.daq, "abort", None)
        if callable(abort) and self.running:
            abort()

    @property
    def compiled_stepping(self) -> bool:
        """True when the DAQ offers a compiled stepping hook (a 20 kHz per-sample loop in real time)."""
        hook = getattr(self.parts.daq, "stepping_hook", None)
        return callable(hook) and hook() is not None

    def execute(
        self, plan: Callable, *args, on_event: Callable | None = None, should_stop: Callable[[], bool] | None = None
    ):
        """Run ``plan(bench, emit, *args)`` on this bench and return its result: the one way a job
        runs a plan, here in the caller's thread (service.runtime.engine runs the same call in the
        bench's own process). ``emit(*payload)`` passes events to ``on_event``; after each one,
        ``should_stop()`` true raises the stop flag, so the plan's loop stops within one period."""

        def emit(*payload) -> None:
            if on_event is not None:
                on_event(*payload)
            if should_stop is not None and should_stop():
                self.request_stop()

        with self.plan_scope():
            if should_stop is not None and should_stop():  # stopped before the plan began: it holds
                self.request_stop()
            return plan(self, emit, *args)

    def cancel_plan(self, job_id: str | None = None) -> None:
        """Stop the plan of job ``job_id`` (its caller also stops it as it begins, ``execute``)."""
        self.request_stop()

    @contextmanager
    def plan_scope(self) -> Iterator[None]:
        """One plan (a job's whole experiment: its preparation and every run in it). It starts with
        the stop flag down; a stop or a trip raised at any time inside it, while the plan is still
        computing its drive as well as during a run, stays raised for the rest of the plan, so every
        later session in it ends at once at 0 V instead of running."""
        with self._lock:
            self._stop_flag[0], self._stop_reason, self.tripped = 0, None, None
            self._plans += 1
        try:
            yield
        finally:
            with self._lock:
                self._plans -= 1

    @property
    def running(self) -> bool:
        """True while a session (a run) owns the bench."""
        return not self._idle.is_set()

    def interrupt_reason(self) -> str | None:
        """Why the running loop must stop now (watchdog trip, stop request), or None."""
        if self.tripped:
            return self.tripped
        if self._stop_flag[0]:
            return self._stop_reason or STOPPED_ON_REQUEST
        return None

    @contextmanager
    def session(self, period_s: float, name: str = "run") -> Iterator[BenchSession]:
        """Own the bench for one run: one at a time, watchdog armed with this loop's control period
        ``period_s`` (s); the DAQ output is at 0 V when the block exits. Outside a plan the stop flag
        is cleared here; inside one (``plan_scope``) a stop raised earlier in the plan still holds."""
        self._ensure_open()
        with self._lock:
            if self._plans == 0:
                self._stop_flag[0], self._stop_reason, self.tripped = 0, None, None
            self._idle.clear()
            try:
                begin = getattr(self.parts.daq, "begin_session", None)
                if begin is not None:
                    begin()
                self.watchdog.arm(period_s, name)
                yield BenchSession(self)
            finally:
                self.watchdog.disarm()
                try:
                    self._to_zero()
                finally:
                    self._idle.set()

    def run(
        self,
        u_v: Mapping[str, np.ndarray],
        sample_rate_hz: float,
        *,
        block_samples: int = RUN_BLOCK_SAMPLES,
        on_block: Callable[[BenchRecord, float], None] | None = None,
        should_stop: Callable[[], bool] | None = None,
    ) -> BenchRecord:
        """Stream a planned waveform through the bench in buffered blocks and return the record.

        ``u_v`` maps axis → actuator volts; axes left out are held at 0 V. ``on_block`` gets the
        record so far and the fraction done; the stop flag and ``should_stop`` are polled before
        every block (one block = one control period here). A stop, a watchdog trip, a device fault
        or sensor saturation raises RunInterrupted carrying the partial record. The output is at
        0 V when this returns or raises.
        """
        self._ensure_open()
        self.check_waveform(u_v, sample_rate_hz)
        lengths = {len(np.asarray(u)) for u in u_v.values()}
        if len(lengths) != 1:
            raise LimitError(f"all axes need the same number of samples, got {sorted(lengths)}")
        n = lengths.pop()
        with self.session(period_s=block_samples / sample_rate_hz, name="a buffered run") as session:
            actual = self.parts.daq.configure(sample_rate_hz)
            if abs(actual - sample_rate_hz) > 1e-9 * sample_rate_hz:
                raise LimitError(
                    f"sample rate {sample_rate_hz} Hz is not a divisor of the DAQ timebase; use {actual} Hz"
                )
            daq = self.parts.daq
            n_ao = daq.capabilities.ao_channels
            commands = {axis: np.asarray(u_v.get(axis, np.zeros(n)), dtype=float) for axis in self.axes}
            acquired = Acquired(self, n, actual)
            previous = {axis: 0.0 for axis in self.axes}
            self.live.begin(actual, "buffered run")
            for start in range(0, n, block_samples):
                if start and should_stop is not None and should_stop():
                    self.request_stop()
                stop = min(start + block_samples, n)
                ao = np.zeros((stop - start, n_ao))
                blocks = {}
                for axis in self.axes:
                    blocks[axis] = self.clamp_block(axis, commands[axis][start:stop], previous[axis], actual)
                    ao[:, self.parts.ao_channel[axis]] = blocks[axis] / self.parts.amplifiers[axis].gain_v_per_v
                why = session.interrupted()  # right before the write: at most this one block follows a stop
                if why:
                    raise acquired.interrupted(why, stopped=not self.tripped)
                previous = {axis: float(blocks[axis][-1]) for axis in self.axes}
                try:
                    ai = daq.write_read(ao)
                except DriverError as exc:  # a transport failed mid-run: keep the blocks measured so far
                    why = session.interrupted()  # a write abandoned by a stop or a watchdog trip says so
                    raise acquired.interrupted(why or f"daq: {exc}", stopped=bool(why) and not self.tripped) from exc
                acquired.add(blocks, ai)
                self.live.push(blocks, acquired.last_x_um(len(ai)))
                session.feed(stop - start)
                fault = self.fault_reason()
                if fault:
                    raise acquired.interrupted(f"{fault} (run stopped at t={stop / actual:.2f} s)")
                if on_block is not None:
                    on_block(acquired.record(), stop / n)
            return acquired.record()

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
        return {
            axis: float(ai[self.parts.ai_channel[axis]]) * self.parts.sensors[axis].scale_um_per_v for axis in self.axes
        }

    def stop(self, reason: str = "emergency stop", wait_s: float | None = None) -> bool:
        """Emergency stop: raise the stop flag and abort the DAQ's output, let the running loop write
        0 V (a buffered block waiting for its slot ends at once; compiled loops check the flag every
        ≤ 50 samples), and write 0 V here if it has not within ``wait_s`` (default ``[safety]
        stop_wait_s``) or if no loop runs. Returns True if a running loop answered. ``last_stop``
        keeps the request's and the 0 V write's ``time.monotonic()`` (s) for latency figures, and
        the amplifier outputs read after it (``output_v``, actuator volts)."""
        requested_s = time.monotonic()
        running = self.running
        self.request_stop(reason)
        answered = self._idle.wait(self.safety.stop_wait_s if wait_s is None else wait_s)
        zero_s = self.last_zero_monotonic_s if running and answered else None
        if not answered:
            self._to_zero()  # the loop did not answer (stalled): 0 V from this thread
        elif self._lock.acquire(blocking=False):
            try:  # no loop owns the bench: make sure anyway
                self._to_zero()
            finally:
                self._lock.release()
        if zero_s is None or zero_s < requested_s:
            zero_s = self.last_zero_monotonic_s
        self.last_stop = {
            "reason": reason,
            "requested_monotonic_s": requested_s,
            "zero_monotonic_s": zero_s,
            "loop_answered": running and answered,
            "output_v": self.output_v(),
        }
        return running and answered

    def trip(self, reason: str) -> None:
        """A fault seen outside the loop (the DAQ's own watchdog expired): the running loop stops as
        on a watchdog trip, a failure with ``reason``, not a stop on request."""
        self._on_watchdog_trip(reason)
        abort = getattr(self.parts.daq, "abort", None)
        if callable(abort) and self.running:
            abort()

    def _on_watchdog_trip(self, reason: str) -> None:
        self.tripped = reason
        self._stop_flag[0] = 1

    def close(self) -> None:
        if self._closed:
            return
        try:
            self._to_zero()
        finally:
            self._closed = True
            self.watchdog.close()
            self.parts.daq.close()

    def __enter__(self) -> Bench:
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
            "amplifiers": {
                a: {"gain_v_per_v": amp.gain_v_per_v, **amp.status().as_dict()}
                for a, amp in self.parts.amplifiers.items()
            },
            "sensors": {
                a: {"scale_um_per_v": s.scale_um_per_v, "range_um": list(s.range_um), **s.status().as_dict()}
                for a, s in self.parts.sensors.items()
            },
            "limits": {
                # the resonance rule too: the sweeps' own limit, not only the amplifier's
                a: {**lim.as_dict(), "max_frequency_hz_at_full_range": highest_sine_hz(lim, lim.v_max_v - lim.v_min_v)}
                for a, lim in self.limits.items()
            },
            "safety": {
                **self.safety.__dict__,
                "watchdog_last_trip": self.watchdog.last_trip,
                "stop_requested": bool(self._stop_flag[0]),
                "running": self.running,
            },
            "modes": {
                "buffered": daq.capabilities.buffered,
                "point_by_point": daq.capabilities.point_by_point,
                "point_by_point_reason": daq.capabilities.point_by_point_reason,
            },
            # real-time pacing of an emulated DAQ: periods paced and overruns (a real DAQ has none)
            "timing": daq.timing() if callable(getattr(daq, "timing", None)) else {"realtime": False},
        }

    def clear_faults(self) -> dict:
        """Clear latched amplifier faults and the watchdog's trip once the cause is understood: the
        operator's reset. Refused (BenchBusy) while a run owns the bench. The outputs stay at 0 V;
        returns the faults that were cleared and any that remain (e.g. a lost sensor, which a reset
        cannot mend) as {"cleared": [...], "remaining": reason | None}."""
        if self.running or not self._lock.acquire(blocking=False):
            raise BenchBusy("a run owns the bench; stop it before resetting faults")
        try:
            cleared = [
                f"amplifier {a}: {st.fault_reason or 'fault'}"
                for a, amp in self.parts.amplifiers.items()
                if (st := amp.status()).fault
            ]
            if self.tripped:
                cleared.append(f"watchdog: {self.tripped}")
            for amp in self.parts.amplifiers.values():
                amp.clear_fault()
            self.tripped = None
            self._to_zero()
            return {"cleared": cleared, "remaining": self.fault_reason()}
        finally:
            self._lock.release()

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
        self.last_zero_monotonic_s = time.monotonic()
        for axis in self.axes:
            self._last_u_v[axis] = 0.0

    def _ensure_open(self) -> None:
        if self._closed:
            raise DriverError("the bench is closed")
