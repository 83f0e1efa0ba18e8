"""A probe on what the emulated amplifiers actually receive and put out, for tests and audits.

The emulated DAQ records one entry per write (a buffered block, a point-by-point period, a 0 V
write, the close): emulated time ``t_s``, the last DAQ volts applied to each amplifier input
``daq_ao_v`` and each amplifier's output ``amplifier_v`` (actuator volts, noise-free); an "idle"
entry (a 0 V write) also has ``zero_from_t_s``, the emulated time the 0 V write began. The last
``keep`` entries stay in memory (``entries()``, ``last()``); with ``[emulator] output_log = PATH``
each entry is also appended to PATH as one JSON line, flushed at once, so a test can read what a
separate ``evcbench serve`` process applied, e.g. after SIGTERM::

    [emulator]
    output_log = "/tmp/evc/output.jsonl"   # optional file; "" = memory only
    output_log_keep = 1000                 # entries kept in memory
    output_stage = "127.0.0.1:40123"       # optional: also send each entry's levels to the emulated
                                           # output stage, a process of its own that holds them
                                           # (drivers/emulated/output_stage.py); "" = none
"""

from __future__ import annotations

import json
import threading
from collections import deque

from drivers.emulated.config import AXES


def check_config(section) -> dict:
    """Validate the ``[emulator]`` table; returns it with defaults filled in."""
    section = dict(section or {})
    for key in section:
        if key not in ("output_log", "output_log_keep", "output_stage"):
            raise ValueError(f"emulator.{key}: unknown key (known: output_log, output_log_keep, output_stage)")
    stage = section.setdefault("output_stage", "")
    if stage:
        from drivers.emulated.output_stage import parse_address  # here: `python -m` runs that module

        parse_address(stage)
    path = section.setdefault("output_log", "")
    keep = section.setdefault("output_log_keep", 1000)
    if not isinstance(path, str):
        raise ValueError(f'emulator.output_log: must be a file path or "", got {path!r}')
    if isinstance(keep, bool) or not isinstance(keep, int) or not 1 <= keep <= 10**6:
        raise ValueError(f"emulator.output_log_keep: must be an integer in 1..1000000, got {keep!r}")
    return section


class OutputLog:
    """Entries of (t_s, event, daq_ao_v per axis, amplifier_v per axis), newest last."""

    def __init__(self, world, section=None):
        cfg = check_config(section)
        self.world = world
        self.path = cfg["output_log"] or None
        self._entries: deque[tuple] = deque(maxlen=cfg["output_log_keep"])
        self._lock = threading.Lock()
        self._file = open(self.path, "a", buffering=1) if self.path else None
        #: the emulated output stage's link (another process holds the levels), or None
        self.stage = None
        if cfg["output_stage"]:
            from drivers.emulated.output_stage import OutputStageLink

            self.stage = OutputStageLink(cfg["output_stage"])

    def record(self, event: str, **extra) -> None:
        """Append the world's present amplifier inputs and outputs as one entry (plus ``extra``).
        Cheap (called once per block or period): a tuple now, the dict only when read."""
        raw = (self.world.time_s, event, self.world.applied_ao_v(), self.world.amplifier_output_v(), extra)
        if self.stage is not None:
            self.stage.send_levels(raw[2], raw[3])
        with self._lock:
            self._entries.append(raw)
            if self._file is not None:
                self._file.write(json.dumps(_entry(raw)) + "\n")

    def entries(self) -> list[dict]:
        with self._lock:
            raws = list(self._entries)
        return [_entry(r) for r in raws]

    def last(self) -> dict | None:
        with self._lock:
            raw = self._entries[-1] if self._entries else None
        return None if raw is None else _entry(raw)

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None


def _entry(raw: tuple) -> dict:
    t_s, event, ao, vout, extra = raw
    return {
        "t_s": round(t_s, 6),
        "event": event,
        "daq_ao_v": {a: float(ao[i]) for i, a in enumerate(AXES)},
        "amplifier_v": {a: float(vout[i]) for i, a in enumerate(AXES)},
        **extra,
    }
