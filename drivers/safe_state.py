"""0 V from a process that is not the bench engine: what the supervisor (service.runtime.supervisor)
does the moment an engine dies or is killed, before a fresh engine starts.

A dead engine's devices are free again (the OS closes its serial port; NI-DAQmx releases a dead
process's tasks), so another process may drive them. Per device, from the bench configuration:

- emulated output stage (``[emulator] output_stage``): a ``zero`` message; it holds 0 V;
- NI-DAQmx DAQ (``[transport] daq = "nidaq"``): an on-demand task writes 0 V to both AO channels;
- MDT693B on a serial port (``[transport.amplifier] kind = "serial"``): every mapped channel's DC
  set-point to 0 V (the modulation input is the DAQ's, zeroed above);
- the in-process emulator: nothing to do, its outputs ended with the engine.

``zero_outputs`` never raises: each device's line says what was done or why it was not.

``SafeOpen`` is the other half: the order a (fresh) bench engine opens its devices in, so that its
first act is 0 V. The output devices come first, each put in its safe state the moment it is open
(the DAQ's analog outputs at 0 V, then the amplifiers disabled); only then are the sensors opened.
"""

from __future__ import annotations

import time

from drivers.interfaces import DriverError


class SafeOpen:
    """Opens a bench output-first: the factory calls ``daq_opened`` as soon as the DAQ is open (0 V
    on its AO at once), ``amplifiers_opened`` as soon as the amplifiers are (each disabled, where
    the driver can), and ``sensors_opened`` last. ``order`` lists each step as (what,
    ``time.monotonic()`` s); ``zero_monotonic_s`` is the DAQ's 0 V write; ``notes`` say what failed."""

    def __init__(self):
        self.order: list[tuple[str, float]] = []
        self.notes: list[str] = []
        self.zero_monotonic_s: float | None = None

    def _note(self, what: str) -> float:
        at = time.monotonic()
        self.order.append((what, at))
        return at

    def daq_opened(self, daq) -> None:
        """The DAQ is open: its analog outputs to 0 V before anything else opens (a failure raises)."""
        self._note("DAQ opened")
        daq.write_idle()
        self.zero_monotonic_s = self._note("DAQ outputs at 0 V")

    def amplifiers_opened(self, amplifiers: dict) -> None:
        """The amplifiers are open: each disabled (an MDT693B's DC set-point to 0 V)."""
        self._note("amplifiers opened")
        for axis, amp in amplifiers.items():
            try:
                amp.disable()
            except Exception as exc:  # noqa: BLE001 - the DAQ's 0 V holds; the note says what failed
                self.notes.append(f"amplifier {axis}: not disabled ({exc})")
        self._note("amplifiers disabled")

    def sensors_opened(self) -> None:
        self._note("sensors opened")

    def amplifiers_enabled(self, amplifiers: dict) -> None:
        """After the safe open, on a first start only (the outputs still at 0 V): each amplifier enabled."""
        for amp in amplifiers.values():
            amp.enable()
        self._note("amplifiers enabled at 0 V")

    def as_dict(self) -> dict:
        return {
            "zero_monotonic_s": self.zero_monotonic_s,
            "order": [[what, at] for what, at in self.order],
            "notes": list(self.notes),
        }


def _stage(address: str) -> str:
    from drivers.emulated.output_stage import OutputStageLink

    link = OutputStageLink(address)
    try:
        link.call("zero", by="the supervisor")
    finally:
        link.close()
    return f"emulated output stage at {address}: 0 V written"


def _nidaq(section: dict) -> str:
    from drivers.nidaq import zero_ao

    channels = zero_ao(**section)
    return f"NI-DAQmx {channels}: 0 V written"


def _serial(section: dict, axes_cfg: dict) -> str:
    from drivers.serial_amplifier import DEFAULT_CHANNEL_MAP, Mdt693b

    if section["port"] == "emulated":
        return "emulated MDT693B: it ended with the engine (its pty was the engine's)"
    controller = Mdt693b(section["port"], timeout_s=section["timeout_s"], retries=section["retries"])
    try:
        mapping = {**DEFAULT_CHANNEL_MAP, **(section.get("channels") or {})}
        channels = [mapping[axis] for axis in axes_cfg]
        for channel in channels:
            controller.set(f"{channel}voltage", 0.0)
    finally:
        controller.close()
    return f"MDT693B on {section['port']}: set-points of channels {', '.join(channels)} at 0 V"


def zero_outputs(config: dict) -> list[str]:
    """Drive every output the bench ``config`` names to 0 V from this process; one line per device
    (empty: nothing outlives the engine). A device that could not be reached says "not written"."""
    notes: list[str] = []
    stage = (config.get("emulator") or {}).get("output_stage")
    transport = config.get("transport")
    steps = []
    if stage:
        steps.append(("emulated output stage", lambda: _stage(stage)))
    if transport:
        from drivers.composed import check_transport

        t = check_transport(dict(transport))
        if t["daq"] == "nidaq":
            steps.append(("NI-DAQmx DAQ", lambda: _nidaq(dict(t.get("nidaq") or {}))))
        if t["amplifier"]["kind"] == "serial":
            steps.append(("MDT693B", lambda: _serial(t["amplifier"], config.get("axes", {}))))
    for name, step in steps:
        try:
            notes.append(step())
        except (DriverError, OSError, TimeoutError, ValueError, KeyError) as exc:
            notes.append(f"{name}: 0 V not written from here ({exc})")
    return notes
