"""Fault injection in the emulator: scheduled faults that the real driver code must survive.

Each fault fires once, ``after_s`` seconds (emulated time) after the start of the bench session
(``Bench.session``: one sweep, one tracking run) that is running or starts next::

    sensor_dropout         the gauge's output sticks at 0 V; its status says dropout      (axis)
    sensor_saturation      the gauge reads full scale (+10 V); its status says saturated  (axis)
    amplifier_overcurrent  the amplifier latches an over-current fault, output to 0 V     (axis)
    serial_disconnect      the MDT693B's serial port goes away (EIO)         (wire benches)
    serial_garbage         the MDT693B answers with garbled numbers          (wire benches)
    can_bus_off            the gauges' CAN bus goes bus-off                  (wire benches)
    daq_underflow          the DAQ's AO buffer underflows: the next write fails
    loop_stall             the loop stops writing samples (its next write blocks) until
                           someone drives the output to 0 V (the watchdog), then fails

Sensor and amplifier faults act on the world's state at the exact sample of a buffered write (the
block is split); in a compiled point-by-point run (one period per call) every fault fires at the
first period boundary at or after its time, at most one period late.
Serial and CAN faults act at the transport (the pty and the CAN bus of drivers/emulated/wire/), so
the real drivers' error handling runs. Faults come from the ``[faults]`` table of a bench
configuration (``[faults.sensor_dropout] axis = "z"  after_s = 0.4``) or from ``add`` (the
service's admin endpoint). ``clear`` removes every fault and recovers what can recover.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import asdict, dataclass

from drivers.emulated.config import AXES
from drivers.interfaces import DriverError

#: kind -> (needs an axis, transport it needs or None, what it does in words)
KINDS: dict[str, tuple[bool, str | None, str]] = {
    "sensor_dropout": (True, None, "dropped out"),
    "sensor_saturation": (True, None, "saturated"),
    "amplifier_overcurrent": (True, None, "tripped on over-current"),
    "serial_disconnect": (False, "serial", "serial port disconnected"),
    "serial_garbage": (False, "serial", "serial port sends garbage"),
    "can_bus_off": (False, "can", "CAN bus off"),
    "daq_underflow": (False, None, "DAQ buffer underflow"),
    "loop_stall": (False, None, "loop stalled"),
}
#: the faults the world itself carries out (the ones that act on an axis's device)
WORLD_KINDS = tuple(kind for kind, (needs_axis, _, _) in KINDS.items() if needs_axis)
STALL_MAX_S = 30.0  # a stalled write gives up after this long even if nobody writes 0 V


class FaultUnavailable(ValueError):
    """The fault needs a part this bench does not have (e.g. a serial fault on an in-process bench)."""


class FaultRequestError(ValueError):
    """A bad fault request: ``field`` names the request field at fault (fault, axis, after_s), ``message`` says why."""

    def __init__(self, field: str, message: str):
        super().__init__(f"{field}: {message}")
        self.field, self.message = field, message


@dataclass
class Fault:
    """One scheduled fault. ``fired_at_s`` is the session time it fired at (s), None while armed;
    ``world_t_s`` the emulator's clock then (as in the output log)."""

    id: int
    kind: str
    axis: str | None
    after_s: float
    source: str
    state: str = "armed"
    fired_at_s: float | None = None
    world_t_s: float | None = None

    def as_dict(self) -> dict:
        return asdict(self)


def check_config(section) -> list[tuple[str, str | None, float]]:
    """Validate a ``[faults]`` table (kind → {axis, after_s}); returns (kind, axis, after_s) tuples."""
    if section is None:
        return []
    if not isinstance(section, dict):
        raise ValueError("faults: must be a table of fault kinds")
    out = []
    for kind, spec in section.items():
        if kind not in KINDS:
            raise ValueError(f"faults.{kind}: unknown fault (known: {', '.join(KINDS)})")
        if not isinstance(spec, dict) or set(spec) - {"axis", "after_s"}:
            raise ValueError(f"faults.{kind}: must be a table with axis and after_s")
        axis, after_s = spec.get("axis"), spec.get("after_s", 0.0)
        if isinstance(after_s, bool) or not isinstance(after_s, (int, float)) or not 0 <= after_s <= 1e6:
            raise ValueError(f"faults.{kind}.after_s: must be a number of seconds in 0..1e6, got {after_s!r}")
        out.append((kind, axis, float(after_s)))
    return out


class FaultInjector:
    """The world's fault schedule. The emulated DAQ calls ``samples_until_due``/``fire_due`` around
    every write, ``begin_session`` at each session start and ``idle_written`` on every 0 V write."""

    def __init__(self, world, config_section=None):
        self.world = world
        self.transports: dict[str, object] = {}  # "serial" → Mdt693bResponder, "can" → EmulatedGaugeNodes
        self._faults: list[Fault] = []
        self._next_id = 1
        self._t0_s = 0.0
        self._lock = threading.Lock()
        self._idle = threading.Event()
        for kind, axis, after_s in check_config(config_section):
            self.add(kind, axis, after_s, source="config", check_transport=False)

    # ------------------------------------------------------------------ schedule
    def add(
        self,
        kind: str,
        axis: str | None = None,
        after_s: float = 0.0,
        source: str = "api",
        check_transport: bool = True,
    ) -> Fault:
        """Schedule a fault; FaultRequestError names a bad kind, axis or time, FaultUnavailable a missing part."""
        if kind not in KINDS:
            raise FaultRequestError("fault", f"unknown fault {kind!r} (known: {', '.join(KINDS)})")
        needs_axis, transport, _ = KINDS[kind]
        if needs_axis and axis not in AXES:
            raise FaultRequestError("axis", f"{kind} needs an axis, one of {', '.join(AXES)}; got {axis!r}")
        if not needs_axis:
            axis = None
        if not math.isfinite(after_s) or after_s < 0:
            raise FaultRequestError("after_s", f"must be a non-negative number of seconds, got {after_s!r}")
        if check_transport and transport and transport not in self.transports:
            raise FaultUnavailable(
                f"fault: {kind} needs the {transport} transport, which this bench does not "
                f"have (use a wire bench such as default_wire)"
            )
        with self._lock:
            fault = Fault(self._next_id, kind, axis, float(after_s), source)
            self._next_id += 1
            self._faults.append(fault)
        return fault

    def list(self) -> list[dict]:
        with self._lock:
            return [f.as_dict() for f in self._faults]

    def clear(self) -> list[str]:
        """Remove every fault, clear latched faults in the world and recover the transports.
        Returns notes on what could not be undone."""
        notes = []
        with self._lock:
            fired = {f.kind for f in self._faults if f.state == "fired"}
            self._faults.clear()
        self._idle.set()  # release a stalled write
        self.world.clear_faults()
        serial, can = self.transports.get("serial"), self.transports.get("can")
        if serial is not None:
            serial.mode = "ok"
        if can is not None:
            can.clear()
        if "serial_disconnect" in fired:
            notes.append("serial_disconnect cannot be undone: the emulated port is closed; restart the service")
        if "can_bus_off" in fired:
            notes.append("can_bus_off: the driver latched the bus failure; restart the service to reconnect")
        return notes

    # ------------------------------------------------------------------ clock
    def begin_session(self) -> None:
        """A bench session starts: ``after_s`` counts from now."""
        self._t0_s = self.world.time_s
        self._idle.clear()

    def session_time_s(self) -> float:
        """Emulated seconds since the current session started."""
        return self.world.time_s - self._t0_s

    def samples_until_due(self, n: int) -> int | None:
        """Samples (0..n-1) that can be written before the next armed fault fires, or None if none
        fires within the next ``n`` samples."""
        if not self._faults:  # the common case, checked once per block or period: no lock, no list
            return None
        dt = 1.0 / self.world.sample_rate_hz
        now = self.session_time_s()
        with self._lock:
            due = [f.after_s for f in self._faults if f.state == "armed"]
        if not due:
            return None
        k = max(0, math.ceil((min(due) - now) / dt - 1e-9))
        return k if k < n else None

    def idle_written(self) -> None:
        """Someone drove the outputs to 0 V (the watchdog, a stop): a stalled write gives up."""
        self._idle.set()

    # ------------------------------------------------------------------ firing
    def fire_due(self) -> None:
        """Fire every armed fault that is due now. A DAQ fault raises DriverError; a stall blocks."""
        now = self.session_time_s()
        with self._lock:
            due = [f for f in self._faults if f.state == "armed" and f.after_s <= now + 1e-9]
            for f in due:
                f.state, f.fired_at_s, f.world_t_s = "fired", now, self.world.time_s
        for f in due:
            self._fire(f, now)

    def _fire(self, f: Fault, t_s: float) -> None:
        if f.kind in WORLD_KINDS:
            self.world.inject_fault(f.kind, f.axis, at_s=t_s)
        elif f.kind == "serial_disconnect":
            self.transports["serial"].unplug()
        elif f.kind == "serial_garbage":
            self.transports["serial"].mode = "garble"
        elif f.kind == "can_bus_off":
            self.transports["can"].inject("bus_off")
        elif f.kind == "daq_underflow":
            raise DriverError(
                f"AO buffer underflow at t={t_s:.2f} s (injected): the host did not supply "
                "samples in time and the DAQ stopped the task"
            )
        elif f.kind == "loop_stall":
            t0 = time.monotonic()
            self._idle.clear()
            self._idle.wait(STALL_MAX_S)
            raise DriverError(
                f"the loop stalled at t={t_s:.2f} s (injected) for {time.monotonic() - t0:.2f} s "
                "until the output was driven to 0 V; this write was abandoned"
            )
