"""The bench engine's pulse: one thread that proves the engine alive, to the web process and to the
hardware.

Every ``PULSE_S`` it writes ``time.monotonic()`` into a shared double that the web process's
supervisor (service.runtime.supervisor) reads: a value older than the supervisor's hang limit
means the engine is hung (stopped, or starved of every core), and the supervisor kills it. The
same beat pets the DAQ's hardware watchdog where the driver has one (``pet_watchdog``: the NI AO
watchdog timer, the emulated output stage's): if the whole engine stops, no beat comes, and the
hardware drives its outputs to 0 V by itself after its own timeout. When the watchdog reports
that it has expired (the engine was stopped longer than that), the running plan is stopped with
the reason, so the job ends saying what happened.

``time.monotonic()`` is CLOCK_MONOTONIC on Linux: the same clock in every process of the machine.
"""

from __future__ import annotations

import logging
import threading
import time

log = logging.getLogger("evcbench.engine")

#: how often the pulse beats (s)
PULSE_S = 0.05


class Pulse:
    """The pulse thread of one engine: ``heartbeat`` is a shared ``double`` (a
    ``multiprocessing.RawValue("d")``) or None; ``bench`` a ``drivers.bench.Bench``."""

    def __init__(self, bench, heartbeat=None, interval_s: float = PULSE_S):
        self.bench, self.heartbeat, self.interval_s = bench, heartbeat, float(interval_s)
        self._pet = None  # set by ``pet_from_now`` once the hardware watchdog is armed
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._run, name="evc-engine-pulse", daemon=True)
        self.expired: str | None = None  # the hardware watchdog's last expiry, in words

    def pet_from_now(self) -> None:
        """The DAQ's watchdog is armed: pet it at every beat (before, an expiry a dead engine left
        would read as this engine's)."""
        self._pet = getattr(self.bench.parts.daq, "pet_watchdog", None)

    def start(self) -> Pulse:
        self.beat()
        self._thread.start()
        return self

    def beat(self) -> None:
        """One beat: the heartbeat, then the hardware watchdog's pet."""
        if self.heartbeat is not None:
            self.heartbeat.value = time.monotonic()
        if self._pet is None:
            return
        try:
            expired = self._pet()
        except Exception as exc:  # noqa: BLE001 - a pet that fails is reported; the beat goes on
            log.warning("hardware watchdog pet failed: %s", exc)
            return
        if expired and expired != self.expired:
            self.expired = expired
            log.error("%s", expired)
            if self.bench.running:
                self.bench.trip(expired)
        elif not expired:
            self.expired = None

    def _run(self) -> None:
        while not self._closing.wait(self.interval_s):
            self.beat()

    def close(self) -> None:
        self._closing.set()
        self._thread.join(1.0)
