"""Real-time pacing of the emulated DAQ (``[daq] realtime = true``): samples take wall time.

Without pacing the emulator runs as fast as the CPU allows, which is right for tests and
identification, but not for what a real bench imposes: a hardware-timed clock that consumes one
sample every 1/fs seconds whether or not the host keeps up. With pacing, each block of ``n``
samples handed to the world is due at ``t0 + produced / fs`` (wall clock, ``time.monotonic``):
the pacer sleeps until then if the host is early, and counts an **overrun** if the host hands
the block over later than ``tolerance_blocks`` block durations after it was due: the DAQ's output
buffer holds two blocks (the one playing and the next one, as the buffered control loop queues
them), so a block later than that finds the buffer run dry. After an overrun the schedule restarts from now, so one stall
counts once. ``idle`` (the output parked at 0 V between runs) stops the clock.

Counters: ``periods`` (blocks paced), ``overruns``, ``max_late_s`` (worst lateness seen).
"""

from __future__ import annotations

import threading
import time


class Pacer:
    """Paces blocks of samples to a sample clock of ``sample_rate_hz`` (Hz)."""

    def __init__(self, tolerance_blocks: float = 2.0):
        self.tolerance_blocks = float(tolerance_blocks)
        self.periods = 0
        self.overruns = 0
        self.max_late_s = 0.0
        self._t0: float | None = None
        self._produced = 0
        self._rate_hz = 0.0
        self._lock = threading.Lock()
        #: set by ``abort``: the sleep for the next slot ends at once (the emergency stop's path)
        self.aborted = threading.Event()

    def tick(self, n: int, sample_rate_hz: float) -> None:
        """A block of ``n`` samples is about to be produced at ``sample_rate_hz``: wait for its slot."""
        if n <= 0:
            return
        with self._lock:
            now = time.monotonic()
            if self._t0 is None or sample_rate_hz != self._rate_hz:
                self._t0, self._produced, self._rate_hz = now, 0, float(sample_rate_hz)
            due = self._t0 + self._produced / self._rate_hz
            late = now - due
            self.periods += 1
            self.max_late_s = max(self.max_late_s, late)
            if late > self.tolerance_blocks * n / self._rate_hz:
                self.overruns += 1
                self._t0, self._produced, due = now, 0, now
            self._produced += n
        wait = due - time.monotonic()
        if wait > 0:
            self.aborted.wait(wait)

    def abort(self) -> None:
        """End a sleeping ``tick`` now and every later one at once, until ``resume`` (a new session)."""
        self.aborted.set()

    def resume(self) -> None:
        self.aborted.clear()

    def stop_clock(self) -> None:
        """The output is parked: the next block starts a new schedule."""
        with self._lock:
            self._t0 = None

    def counters(self) -> dict:
        """``{"realtime": True, "periods", "overruns", "max_late_ms"}``."""
        return {
            "realtime": True,
            "periods": self.periods,
            "overruns": self.overruns,
            "max_late_ms": round(self.max_late_s * 1e3, 3),
        }
