"""The emulated output stage in a process of its own: the DAQ's analog outputs and the amplifiers'
outputs as the hardware holds them, with the DAQ's watchdog timer.

On real hardware the DAQ's AO channels and the MDT693B keep their last voltage when the process
that drives them dies. The in-process emulator cannot show that: its world dies with the engine.
With ``[emulator] output_stage = "127.0.0.1:PORT"`` the emulated DAQ also sends every level it
applies (each block's last row, each period, each 0 V write: the output log's entries) to this
process, which *holds* it: kill the engine and the stage still reads the voltage last driven.

The watchdog is NI-DAQmx's AO watchdog timer (``DAQmxCfgWatchdogAOExpirStates``) in miniature: once
armed with a timeout (s), a pet must come within it, or the stage drives every output to its
expiration state, 0 V, by itself, and stays there (ignoring new levels) until cleared. No host
process writes that 0 V.

The timer is the device's, not this process's: every host message carries the moment it was sent
(``at``, ``time.monotonic()``), as a write reaches a DAQ within microseconds, and the stage takes
the messages in order on that clock. The watchdog expires at its deadline (the last pet sent +
the timeout), exactly, whenever this process gets the core to notice (it wakes at the deadline,
and at least every tenth of the timeout): the outputs read 0 V from the deadline on, and a pet
queued while the stage was starved still counts when it was sent, so the stage's own lateness
under load neither delays an expiry nor makes a false one. ``acted_late_s`` says how late the
stage noticed its last expiry (the emulation's lateness, not the device's).

Run it with ``python -m drivers.emulated.output_stage [--port N] [--no-watchdog]``: it prints its
address on the first line of stdout. One UDP datagram of JSON per message, ``op`` naming it, and ``at``, the sender's clock:

    set    {"ao": [y, z], "amp": [y, z]}   DAQ volts and amplifier volts; no answer
    arm    {"timeout_s": t}               → {"armed_s": t}
    pet                                   → {"expired": reason | null}
    clear                                 → {"cleared": was_expired}
    zero   {"by": who}                    → {"zero_monotonic_s": t}: another process writes 0 V
    state                                 → levels, watchdog and ``zero_since_monotonic_s``
    honour {"on": bool}                   → its expiry acts (or not: a DAQ without a watchdog) from now on

Times are ``time.monotonic()`` seconds: CLOCK_MONOTONIC, one clock for every process of the machine.
"""

from __future__ import annotations

import argparse
import json
import select
import socket
import sys
import threading
import time
from collections import deque

#: below this (V, every output) the stage counts as at 0 V
ZERO_V = 0.010
#: the stage looks at its armed watchdog at least this often, as a fraction of its timeout
POLL_FRACTION = 0.1
#: how long the stage waits for a message while no watchdog is armed (s)
IDLE_WAIT_S = 0.1
#: how long a client waits for an answer (s)
ANSWER_TIMEOUT_S = 0.5


def parse_address(text: str) -> tuple[str, int]:
    """``"host:port"`` → (host, port)."""
    host, _, port = str(text).rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f'emulator.output_stage: must be "host:port", got {text!r}')
    return host, int(port)


class StageState:
    """What the stage holds; every method takes the present ``time.monotonic()`` (s)."""

    def __init__(self, honour_watchdog: bool = True):
        self.honour = honour_watchdog
        self.ao_v, self.amp_v = [0.0, 0.0], [0.0, 0.0]
        self.timeout_s: float | None = None  # armed watchdog's timeout
        self.last_pet_s = 0.0
        self.expired: str | None = None
        self.expired_at_s: float | None = None
        self.acted_late_s: float | None = None
        self.zero_since_s: float | None = time.monotonic()
        self.events: deque = deque(maxlen=64)

    def _levels(self, now: float, ao, amp, what: str) -> None:
        was_zero = self.zero_since_s is not None
        self.ao_v, self.amp_v = [float(v) for v in ao], [float(v) for v in amp]
        zero = all(abs(v) < ZERO_V for v in self.amp_v + self.ao_v)
        if zero and not was_zero:
            self.zero_since_s = now
            self.events.append((now, f"0 V ({what})"))
        elif not zero:
            self.zero_since_s = None

    def set(self, now: float, ao, amp) -> None:
        if self.expired is None:  # an expired watchdog holds the expiration states
            self._levels(now, ao, amp, "written")

    def arm(self, now: float, timeout_s: float) -> float:
        self.timeout_s, self.last_pet_s, self.expired, self.expired_at_s = float(timeout_s), now, None, None
        self.events.append((now, f"watchdog armed ({timeout_s:g} s)"))
        return self.timeout_s

    def pet(self, now: float) -> str | None:
        self.last_pet_s = max(self.last_pet_s, now)
        return self.expired

    def clear(self, now: float) -> bool:
        was, self.expired, self.expired_at_s, self.last_pet_s = self.expired is not None, None, None, now
        return was

    def zero(self, now: float, by: str) -> float:
        self._levels(now, [0.0, 0.0], [0.0, 0.0], f"written by {by}")
        return now

    def deadline_s(self) -> float | None:
        """When the armed watchdog expires without another pet (monotonic s), or None."""
        if self.timeout_s is None or not self.honour or self.expired is not None:
            return None
        return self.last_pet_s + self.timeout_s

    def wait_s(self, now: float) -> float:
        """How long the stage may wait for a message at ``now`` before it must look at the watchdog."""
        deadline = self.deadline_s()
        if deadline is None:
            return IDLE_WAIT_S
        return min(max(0.0, deadline - now), POLL_FRACTION * self.timeout_s)

    def tick(self, now: float) -> None:
        """Expire the watchdog if its deadline passed by ``now``: every output to 0 V, by the stage
        itself, from the deadline on (the device's timer, however late this process noticed)."""
        deadline = self.deadline_s()
        if deadline is None or now < deadline:
            return
        self.expired_at_s, self.acted_late_s = deadline, now - deadline
        self.expired = (
            f"DAQ watchdog expired: no pet within {self.timeout_s:g} s (the last at "
            f"{self.last_pet_s:.3f} s monotonic); the DAQ drove its outputs to 0 V by itself"
        )
        self._levels(deadline, [0.0, 0.0], [0.0, 0.0], "watchdog expired")

    def as_dict(self) -> dict:
        return {
            "daq_ao_v": list(self.ao_v),
            "amplifier_v": list(self.amp_v),
            "zero_since_monotonic_s": self.zero_since_s,
            "watchdog": {
                "honoured": self.honour,
                "timeout_s": self.timeout_s,
                "last_pet_monotonic_s": self.last_pet_s,
                "expired": self.expired,
                "expired_at_monotonic_s": self.expired_at_s,
                "acted_late_s": self.acted_late_s,
            },
            "events": [list(e) for e in self.events],
        }


def _answer(state: StageState, message: dict, now: float) -> dict | None:
    op = message.get("op")
    if op == "set":
        state.set(now, message["ao"], message["amp"])
        return None
    if op == "arm":
        return {"armed_s": state.arm(now, message["timeout_s"])}
    if op == "pet":
        return {"expired": state.pet(now)}
    if op == "clear":
        return {"cleared": state.clear(now)}
    if op == "zero":
        return {"zero_monotonic_s": state.zero(now, str(message.get("by", "?")))}
    if op == "honour":
        state.honour, state.last_pet_s = bool(message["on"]), now
        return {"honoured": state.honour}
    return {**state.as_dict(), "now_monotonic_s": now}


def _take(sock: socket.socket, state: StageState) -> None:
    """Every message waiting on ``sock``, in order, each at the moment it was sent: the watchdog is
    looked at on that clock before the message acts (a pet sent after the deadline does not save it)."""
    while True:
        try:
            data, peer = sock.recvfrom(65536)
        except BlockingIOError:
            return
        now = time.monotonic()
        try:
            message = json.loads(data)
            at = min(float(message.get("at", now)), now)
            state.tick(at)
            reply = _answer(state, message, at)
        except (ValueError, KeyError, TypeError) as exc:
            reply = {"error": f"{type(exc).__name__}: {exc}"}
        if reply is not None:
            sock.sendto(json.dumps(reply).encode(), peer)


def serve(sock: socket.socket, state: StageState, stop: threading.Event | None = None) -> None:
    """Answer datagrams on ``sock`` and keep the watchdog, until ``stop`` is set."""
    sock.setblocking(False)
    while stop is None or not stop.is_set():
        select.select([sock], [], [], state.wait_s(time.monotonic()))
        _take(sock, state)
        state.tick(time.monotonic())


class OutputStageLink:
    """A host's side of the stage: ``send_levels`` never waits (the loop calls it every block);
    ``call`` waits at most ``ANSWER_TIMEOUT_S`` for the answer."""

    def __init__(self, address: str):
        self.address = parse_address(address)
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setblocking(False)
        self._lock = threading.Lock()

    def send_levels(self, ao_v, amp_v) -> None:
        message = {"op": "set", "ao": [float(v) for v in ao_v], "amp": [float(v) for v in amp_v]}
        message["at"] = time.monotonic()
        try:
            self._sock.sendto(json.dumps(message).encode(), self.address)
        except OSError:
            pass  # a stage that is gone: the world in this process still runs (it is only a probe)

    def call(self, op: str, **fields) -> dict:
        """Send ``op`` and return its answer; OSError/TimeoutError if the stage does not answer."""
        with self._lock:
            while True:  # drop a late answer of an earlier call
                try:
                    self._sock.recv(65536)
                except BlockingIOError:
                    break
            message = json.dumps({"op": op, **fields, "at": time.monotonic()}).encode()
            self._sock.sendto(message, self.address)
            if not select.select([self._sock], [], [], ANSWER_TIMEOUT_S)[0]:
                raise TimeoutError(f"the emulated output stage at {self.address[0]}:{self.address[1]} did not answer")
            return json.loads(self._sock.recv(65536))

    def close(self) -> None:
        self._sock.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="the emulated output stage, in a process of its own")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--no-watchdog", action="store_true", help="a DAQ without a watchdog timer")
    args = parser.parse_args(argv)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((args.host, args.port))
    host, port = sock.getsockname()
    print(f"{host}:{port}", flush=True)
    try:
        serve(sock, StageState(honour_watchdog=not args.no_watchdog))
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
