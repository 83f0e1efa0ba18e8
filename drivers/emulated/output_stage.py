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

Run it with ``python -m drivers.emulated.output_stage [--port N] [--no-watchdog]``: it prints its
address on the first line of stdout. One UDP datagram of JSON per message, ``op`` naming it:

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
#: how often the stage looks at its watchdog (s)
POLL_S = 0.002
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
        self.last_pet_s = now
        return self.expired

    def clear(self, now: float) -> bool:
        was, self.expired, self.expired_at_s, self.last_pet_s = self.expired is not None, None, None, now
        return was

    def zero(self, now: float, by: str) -> float:
        self._levels(now, [0.0, 0.0], [0.0, 0.0], f"written by {by}")
        return now

    def tick(self, now: float) -> None:
        """Expire the watchdog if its pet is overdue: every output to 0 V, by the stage itself."""
        if self.timeout_s is None or not self.honour or self.expired is not None:
            return
        late_s = now - self.last_pet_s
        if late_s > self.timeout_s:
            self.expired_at_s = now
            self.expired = (
                f"DAQ watchdog expired: no pet for {late_s:.3f} s (timeout {self.timeout_s:g} s); "
                "the DAQ drove its outputs to 0 V by itself"
            )
            self._levels(now, [0.0, 0.0], [0.0, 0.0], "watchdog expired")

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


def serve(sock: socket.socket, state: StageState, stop: threading.Event | None = None) -> None:
    """Answer datagrams on ``sock`` and keep the watchdog, until ``stop`` is set."""
    while stop is None or not stop.is_set():
        ready, _, _ = select.select([sock], [], [], POLL_S)
        now = time.monotonic()
        state.tick(now)
        if not ready:
            continue
        data, peer = sock.recvfrom(65536)
        try:
            reply = _answer(state, json.loads(data), time.monotonic())
        except (ValueError, KeyError, TypeError) as exc:
            reply = {"error": f"{type(exc).__name__}: {exc}"}
        if reply is not None:
            sock.sendto(json.dumps(reply).encode(), peer)


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
            self._sock.sendto(json.dumps({"op": op, **fields}).encode(), self.address)
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
