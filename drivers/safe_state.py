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
"""

from __future__ import annotations

from drivers.interfaces import DriverError


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
