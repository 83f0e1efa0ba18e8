"""A bench assembled per part from its configuration: emulated in-process, serial, CAN or NI-DAQmx.

A bench TOML may carry a ``[transport]`` table (checked here; the emulator's own keys are
checked by drivers.emulated.config)::

    [transport]
    daq = "emulated"                 # "emulated" (in-process world) | "nidaq"
    [transport.amplifier]
    kind = "serial"                  # "emulated" | "serial" (Thorlabs MDT693B)
    port = "emulated"                # device path or pyserial URL; "emulated" = the emulator on a pty
    channels = { y = "x", z = "y" }  # bench axis -> controller channel
    timeout_s = 0.2
    retries = 2
    [transport.sensors]
    kind = "can"                     # "emulated" | "can" (CANopen-style gauge nodes)
    interface = "virtual"            # any python-can interface: virtual, socketcan, pcan, ...
    channel = "emulated"             # "emulated" = a private virtual bus served by the emulator
    node_ids = { y = 1, z = 2 }
    timeout_s = 0.5
    resolution_nm = 1
    filter_hz = 0
    positions = "can"                # "can": every sample in TPDO bursts; "ai": gauges on the DAQ's AI,
                                     # CAN for configuration, EMCY and bus errors only
    [transport.nidaq]                # only with daq = "nidaq"; see drivers/nidaq.py
    device = "Dev1"

"emulated" endpoints need daq = "emulated": the world that simulates the physics serves them.
Physical amplifier constants (gain, slew, current, load) come from ``axes.<axis>.amplifier``.
"""

from __future__ import annotations

import uuid
from collections.abc import Sequence

import numpy as np

from drivers.bench import Bench
from drivers.interfaces import BenchParts, DriverError

AXES = ("y", "z")
_ALLOWED = {
    "": {"daq", "amplifier", "sensors", "nidaq"},
    "amplifier": {"kind", "port", "channels", "timeout_s", "retries"},
    "sensors": {
        "kind",
        "interface",
        "channel",
        "node_ids",
        "timeout_s",
        "resolution_nm",
        "filter_hz",
        "bitrate",
        "positions",
    },
}


def check_transport(t: dict) -> dict:
    """Validate a ``[transport]`` table; fill defaults. Raises ValueError naming the key."""
    for section, keys in _ALLOWED.items():
        table = t if not section else t.get(section, {})
        if not isinstance(table, dict):
            raise ValueError(f"transport.{section}: must be a table")
        for key in table:
            if key not in keys:
                raise ValueError(f"transport.{section + '.' if section else ''}{key}: unknown key")
    daq = t.get("daq", "emulated")
    amp = {
        "kind": "emulated",
        "port": "emulated",
        "channels": {"y": "x", "z": "y"},
        "timeout_s": 0.2,
        "retries": 2,
        **t.get("amplifier", {}),
    }
    sen = {
        "kind": "emulated",
        "interface": "virtual",
        "channel": "emulated",
        "node_ids": {"y": 1, "z": 2},
        "timeout_s": 0.5,
        "resolution_nm": 1,
        "filter_hz": 0,
        "positions": "can",
        **t.get("sensors", {}),
    }
    if daq not in ("emulated", "nidaq"):
        raise ValueError(f"transport.daq: must be 'emulated' or 'nidaq', got {daq!r}")
    if amp["kind"] not in ("emulated", "serial"):
        raise ValueError(f"transport.amplifier.kind: must be 'emulated' or 'serial', got {amp['kind']!r}")
    if sen["positions"] not in ("can", "ai"):
        raise ValueError(f"transport.sensors.positions: must be 'can' or 'ai', got {sen['positions']!r}")
    if sen["kind"] not in ("emulated", "can"):
        raise ValueError(f"transport.sensors.kind: must be 'emulated' or 'can', got {sen['kind']!r}")
    if daq == "nidaq" and "emulated" in (
        amp["kind"],
        sen["kind"],
        amp["port"] if amp["kind"] == "serial" else "",
        sen["channel"] if sen["kind"] == "can" else "",
    ):
        raise ValueError("transport.daq: 'nidaq' drives real hardware; emulated parts need daq = 'emulated'")
    if set(amp["channels"]) != set(AXES) or len(set(amp["channels"].values())) != 2:
        raise ValueError(f"transport.amplifier.channels: need distinct channels for y and z, got {amp['channels']}")
    ids = sen["node_ids"]
    if (
        set(ids) != set(AXES)
        or len(set(ids.values())) != 2
        or not all(isinstance(v, int) and 1 <= v <= 127 for v in ids.values())
    ):
        raise ValueError(f"transport.sensors.node_ids: need distinct ids 1..127 for y and z, got {ids}")
    return {"daq": daq, "amplifier": amp, "sensors": sen, "nidaq": t.get("nidaq", {})}


class ComposedDaq:
    """The fast analog path, with gauge AI columns replaced by positions read over CAN (if any).

    ``positions`` "can": a CAN failure raises DriverError; the Bench then stops, keeps the data so
    far and idles. "ai": the AI columns stay; EMCY and error frames are handled after each block
    and show in the sensors' status (the Bench then stops with the block kept)."""

    def __init__(
        self, inner, can_bus=None, sensors=None, ai_channel=None, closers=(), emulators=None, positions: str = "can"
    ):
        self.inner, self.can_bus, self.sensors, self.positions = inner, can_bus, sensors or {}, positions
        self.ai_channel = ai_channel or {"y": 0, "z": 1}
        self.capabilities = inner.capabilities
        self.emulators = emulators or {}
        self._closers = list(closers)

    @property
    def sample_rate_hz(self) -> float:
        return self.inner.sample_rate_hz

    def configure(self, sample_rate_hz: float) -> float:
        return self.inner.configure(sample_rate_hz)

    def _positions(self, ai: np.ndarray) -> np.ndarray:
        if self.can_bus is None:
            return ai
        if self.positions == "ai":
            try:
                self.can_bus.poll()
            except DriverError:
                pass  # latched in the bus; the sensors' status reports it after this block
            return ai
        block = np.array(np.atleast_2d(ai), dtype=float, copy=True)
        got = self.can_bus.sync_read(block.shape[0])
        for axis, x_um in got.items():
            block[:, self.ai_channel[axis]] = x_um / self.sensors[axis].scale_um_per_v
        return block if np.ndim(ai) == 2 else block[0]

    def write_read(self, ao_daq_v: np.ndarray) -> np.ndarray:
        return self._positions(self.inner.write_read(ao_daq_v))

    def step(self, ao_daq_v: Sequence[float]) -> np.ndarray:
        return self._positions(self.inner.step(ao_daq_v))

    def write_idle(self) -> None:
        self.inner.write_idle()

    def arm_watchdog(self, timeout_s: float) -> dict | None:
        """The inner DAQ's hardware watchdog (NI AO watchdog, emulated output stage), if it has one."""
        arm = getattr(self.inner, "arm_watchdog", None)
        return None if arm is None else arm(timeout_s)

    def pet_watchdog(self) -> str | None:
        pet = getattr(self.inner, "pet_watchdog", None)
        return None if pet is None else pet()

    def clear_watchdog(self) -> None:
        clear = getattr(self.inner, "clear_watchdog", None)
        if clear is not None:
            clear()

    def begin_session(self) -> None:
        """Optional DAQ hook (the emulator's fault clock); real DAQs need none."""
        begin = getattr(self.inner, "begin_session", None)
        if begin is not None:
            begin()

    def close(self) -> None:
        try:
            self.inner.close()
        finally:
            for close in reversed(self._closers):
                try:
                    close()
                except Exception:  # noqa: BLE001 - best effort; the output is already at 0 V
                    pass
            self._closers.clear()


def open_from_config(cfg: dict, seed: int = 0, safe_open=None) -> Bench:
    """Build each part as ``cfg["transport"]`` says (all emulated in-process when absent), output
    first: the DAQ, the amplifiers, then the sensors. ``safe_open`` (drivers.safe_state.SafeOpen)
    puts the DAQ's outputs at 0 V as it opens and disables the amplifiers as they open, before any
    sensor is opened."""
    t = check_transport(cfg.get("transport", {}))
    closers: list = []
    emulators: dict = {}
    world = None
    try:
        if t["daq"] == "emulated":
            from drivers.emulated import World, build_devices

            world = World(cfg, seed)
            daq, amps, sensors = build_devices(world)
        else:
            from drivers.nidaq import NidaqDaq

            try:
                daq, amps, sensors = NidaqDaq(**t["nidaq"]), {}, {}
            except TypeError as exc:
                raise ValueError(f"transport.nidaq: {exc}") from None
        closers.append(daq.close)
        if safe_open is not None:
            safe_open.daq_opened(daq)
        if t["amplifier"]["kind"] == "serial":
            amps = _serial_amplifiers(cfg, t["amplifier"], world, emulators, closers)
        if safe_open is not None:
            safe_open.amplifiers_opened(amps)
        if t["sensors"]["kind"] == "can":
            can_bus, sensors = _can_sensors(t["sensors"], world, emulators, closers)
        else:
            can_bus = None
        if safe_open is not None:
            safe_open.sensors_opened()
        if world is not None:
            world.faults.transports.update(emulators)  # serial / CAN faults act on the wire
        if world is not None and emulators:
            from drivers.emulated.wire import WireDaq

            daq = WireDaq(daq, emulators.get("serial"), emulators.get("can"))
        # closers[0] is the inner DAQ's close, which ComposedDaq.close calls first itself
        composed = ComposedDaq(
            daq,
            can_bus,
            sensors if can_bus else None,
            closers=closers[1:],
            emulators=emulators,
            positions=t["sensors"]["positions"],
        )
    except Exception:
        for close in reversed(closers):
            try:
                close()
            except Exception:  # noqa: BLE001
                pass
        raise
    kinds = f"daq={t['daq']}, amplifier={t['amplifier']['kind']}, sensors={t['sensors']['kind']}"
    resonance = {ax: world.resonance_hz(ax) for ax in AXES} if world is not None else {}
    parts = BenchParts(
        daq=composed,
        amplifiers=amps,
        sensors=sensors,
        resonance_hz=resonance,
        backend=f"composed:{cfg.get('name', '?')} ({kinds})",
        config=cfg,
        world=world,
    )
    return Bench(parts)


def _serial_amplifiers(cfg, a, world, emulators, closers):
    from drivers.serial_amplifier import open_amplifiers

    port = a["port"]
    if port == "emulated":
        if world is None:
            raise DriverError("transport.amplifier.port 'emulated' needs the emulated world")
        from drivers.emulated.wire import Mdt693bResponder

        responder = Mdt693bResponder(world, {ch: axis for axis, ch in a["channels"].items()})
        emulators["serial"] = responder
        closers.append(responder.close)
        port = responder.port
    axes_cfg = {axis: cfg["axes"][axis]["amplifier"] for axis in AXES}
    ctl, amps = open_amplifiers(
        port, axes_cfg, channel_map=a["channels"], timeout_s=a["timeout_s"], retries=a["retries"]
    )
    closers.append(ctl.close)
    return amps


def _can_sensors(s, world, emulators, closers):
    from drivers.can_sensor import CanDisplacementSensor, CanGaugeBus

    channel = s["channel"]
    if channel == "emulated":
        if world is None:
            raise DriverError("transport.sensors.channel 'emulated' needs the emulated world")
        from drivers.emulated.wire import EmulatedGaugeNodes

        channel = f"evc-emulated-{uuid.uuid4().hex[:8]}"
        nodes = EmulatedGaugeNodes(
            world, s["node_ids"], interface=s["interface"], channel=channel, stream=s["positions"] == "can"
        )
        emulators["can"] = nodes
        closers.append(nodes.close)
    bus = CanGaugeBus(
        s["node_ids"], interface=s["interface"], channel=channel, timeout_s=s["timeout_s"], bitrate=s.get("bitrate")
    )
    closers.append(bus.close)
    sensors = {
        axis: CanDisplacementSensor(bus, axis, resolution_nm=s["resolution_nm"], filter_hz=s["filter_hz"])
        for axis in AXES
    }
    return bus, sensors
