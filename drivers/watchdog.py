"""A watchdog thread that drives the outputs to 0 V when a control or acquisition loop stalls.

It is independent of the request handlers and of the loop it guards: the loop ``feed``s it on
every written sample or block; if nothing is written for ``timeout_s`` (``periods`` control
periods, at least ``min_timeout_s``), the watchdog writes 0 V through the DAQ interface
(``write_idle``) and reports the trip, with the reason in words, to ``on_trip``.

Drivers know no service: this module knows only the ``Daq`` protocol. Configuration is the
``[safety]`` table of a bench configuration::

    [safety]
    watchdog_periods = 4        # control periods without a written sample before the trip
    watchdog_min_s = 1.0        # floor of the timeout (slow sweeps, blocks of ≥ 0.1 s), seconds
    watchdog_poll_s = 0.005     # how often the thread looks, seconds
    stop_wait_s = 0.5           # emergency stop: how long to wait for the loop to reach 0 V itself
    unread_limit_s = 10.0       # a run whose measured samples nobody has taken for this long stops at 0 V
    hardware_watchdog_s = 1.0   # the DAQ's own watchdog timer (NI AO watchdog, emulated output stage); 0 = off
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, fields

#: the watchdog's own thread not looking for longer than this (s; or half the timeout) is a pause of
#: its process, not a stall of its loop: above the worst thread delay measured under load, 0.34 s
#: (docs/architecture.md, "Supervision"), for a short timeout as well
PAUSE_S = 0.4

_LIMITS = {
    "watchdog_periods": (1.0, 1000.0),
    "watchdog_min_s": (0.001, 3600.0),
    "watchdog_poll_s": (0.0005, 1.0),
    "stop_wait_s": (0.0, 60.0),
    "unread_limit_s": (0.1, 3600.0),
    "hardware_watchdog_s": (0.0, 60.0),
}


@dataclass(frozen=True)
class SafetyConfig:
    """The ``[safety]`` table: watchdog timeout = max(watchdog_periods × period_s, watchdog_min_s)."""

    watchdog_periods: float = 4.0
    watchdog_min_s: float = 1.0
    watchdog_poll_s: float = 0.005
    stop_wait_s: float = 0.5
    #: the host that records a run (the service, in the bench engine's case) took none of its samples
    #: for this long (s): the run stops at 0 V rather than measure what nobody keeps
    unread_limit_s: float = 10.0
    #: the DAQ's own watchdog timer (s; 0: not armed), where the driver has one: if the bench engine
    #: stops petting it for this long (killed, stopped), the hardware drives its outputs to 0 V itself
    hardware_watchdog_s: float = 1.0

    @classmethod
    def from_config(cls, section: dict | None) -> SafetyConfig:
        """Validate a ``[safety]`` table; raises ValueError naming the bad key."""
        section = section or {}
        if not isinstance(section, dict):
            raise ValueError("safety: must be a table")
        known = {f.name for f in fields(cls)}
        for key, value in section.items():
            if key not in known:
                raise ValueError(f"safety.{key}: unknown key (known: {', '.join(sorted(known))})")
            lo, hi = _LIMITS[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= value <= hi:
                raise ValueError(f"safety.{key}: must be a number in {lo:g}..{hi:g}, got {value!r}")
        return cls(**{k: float(v) for k, v in section.items()})

    def timeout_s(self, period_s: float) -> float:
        """The watchdog timeout for a loop whose control period (or block) is ``period_s`` seconds."""
        return max(self.watchdog_periods * float(period_s), self.watchdog_min_s)


class Watchdog:
    """Guards one loop at a time: ``arm(period_s)``, ``feed()`` per write, ``disarm()`` at the end.

    ``last_trip`` holds the last trip as a dict:

    - ``reason`` in words, ``timeout_s`` (the limit, seconds);
    - ``stalled_s``: the gap that tripped it, from the last feed to the moment the watchdog decided
      (seconds; ≥ ``timeout_s``), and ``samples_fed`` before that moment;
    - ``at_monotonic_s``: that moment (``time.monotonic()``);
    - ``zero_v_s``: from that moment until ``write_idle`` returned (seconds), ``zero_v_at_monotonic_s``;
    - ``fed_during_zero_v``: samples the loop still fed while 0 V was being written (normally 0).

    A loop that feeds again while ``write_idle`` runs does not shrink the reported gap.

    The watchdog judges only time it watched: if its own thread could not look for longer than
    ``PAUSE_S`` or half the timeout (the whole process was stopped, SIGSTOP, or starved), the loop was
    paused with it, not stalled by itself, and its count starts again from that look (``pauses``
    counts them). Without that, a loop resuming with its process met a trip writing 0 V at once."""

    def __init__(self, daq, config: SafetyConfig | None = None, on_trip: Callable[[str], None] | None = None):
        self.daq = daq
        self.config = config or SafetyConfig()
        self.on_trip = on_trip
        self.timeout_s = self.config.watchdog_min_s
        self.period_s = 0.0
        self.name = ""
        self.last_trip: dict | None = None
        self.pauses = 0
        self._armed = False
        self._last_feed = time.monotonic()
        self._fed = 0
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._closed = False
        self._thread: threading.Thread | None = None

    def arm(self, period_s: float, name: str = "run") -> float:
        """Start guarding a loop whose control period is ``period_s``; returns the timeout (s)."""
        with self._lock:
            self.period_s, self.name = float(period_s), name
            self.timeout_s = self.config.timeout_s(period_s)
            self._last_feed, self._fed, self._armed = time.monotonic(), 0, True
        if self._thread is None or not self._thread.is_alive():
            self._thread = threading.Thread(target=self._watch, name="evc-watchdog", daemon=True)
            self._thread.start()
        self._wake.set()
        return self.timeout_s

    def feed(self, samples: int = 1) -> None:
        """The loop wrote ``samples`` more samples (cheap: one clock read)."""
        self._last_feed = time.monotonic()
        self._fed += samples

    def disarm(self) -> None:
        with self._lock:
            self._armed = False

    def close(self) -> None:
        self._closed = True
        self._armed = False
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)

    def _watch(self) -> None:
        looked_s = time.monotonic()
        while not self._closed:
            if not self._armed:  # parked (no polling) until arm() or close() wakes it
                self._wake.wait()
                self._wake.clear()
                looked_s = time.monotonic()
                continue
            self._wake.wait(self.config.watchdog_poll_s)
            self._wake.clear()
            with self._lock:
                if not self._armed:
                    continue
                decided_s, last_feed_s, fed = time.monotonic(), self._last_feed, self._fed
                paused = decided_s - looked_s > max(self.timeout_s / 2, PAUSE_S)
                looked_s = decided_s
                if paused:  # this thread was not running either: the gap is not the loop's
                    self.pauses += 1
                    self._last_feed = max(self._last_feed, decided_s)
                    continue
                if decided_s - last_feed_s < self.timeout_s:
                    continue
                self._armed = False
            self._trip(decided_s, decided_s - last_feed_s, fed)

    def _trip(self, decided_s: float, stalled_s: float, fed: int) -> None:
        """Abort the DAQ's output (where it can: a write waiting for its slot ends at once, later
        ones are refused), write 0 V and report. ``stalled_s`` is the gap seen when the trip was
        decided (at the monotonic time ``decided_s``, seconds), ``fed`` the samples fed until then."""
        try:
            abort = getattr(self.daq, "abort", None)
            if callable(abort):
                abort()
            self.daq.write_idle()
            zero = "output set to 0 V"
        except Exception as exc:  # noqa: BLE001 - report it; the trip itself must not die
            zero = "writing 0 V failed"
            failure = f": {exc}"
        else:
            failure = ""
        zero_at_s = time.monotonic()
        zero_v_s = zero_at_s - decided_s
        reason = (
            f"watchdog: no sample written for {stalled_s:.2f} s during {self.name} (limit "
            f"{self.timeout_s:.2f} s = max({self.config.watchdog_periods:g} periods of "
            f"{self.period_s * 1e3:.1f} ms, {self.config.watchdog_min_s:g} s)); "
            f"{zero} {zero_v_s * 1e3:.1f} ms after the trip{failure}"
        )
        self.last_trip = {
            "reason": reason,
            "timeout_s": self.timeout_s,
            "stalled_s": stalled_s,
            "samples_fed": fed,
            "at_monotonic_s": decided_s,
            "zero_v_s": zero_v_s,
            "zero_v_at_monotonic_s": zero_at_s,
            "fed_during_zero_v": self._fed - fed,
        }
        if self.on_trip is not None:
            self.on_trip(reason)
