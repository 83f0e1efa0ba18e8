"""Thorlabs MDT693B piezo controller over a serial port (pyserial): set-up, slow set-points, limits, status.

The fast path stays the DAQ into the amplifier's modulation (external) input; this driver only
sets the controller up and watches it. Bench axis Y → controller channel ``x``, Z → ``y`` (configurable).

Line format: 115200 baud, 8 data bits, no parity, 1 stop bit, no flow control.

Framing (the whole protocol is this table plus ``FRAME``)::

    host   → <command> CR                      e.g. b"xvoltage?\\r"
    device → [echo of <command> CR] <body> PROMPT
             echo is present when the controller's echo is on (the default) and absent otherwise
             PROMPT is b">"; a reply is complete only when it arrives

    kind     command examples                      body (after the echo)
    -------  ------------------------------------  ------------------------------------------
    query    xvoltage? ymin? xmax? vlimit?         b"*[" number b"]" CR     e.g. b"*[  24.80]\\r"
    id       id?                                   free text lines, each ending in CR
    setter   xvoltage=12.5  xyzvoltage=1,2,3        empty
             xmin=0  xmax=150  echo=1
    unknown  anything else                         b"CMD_NOT_DEFINED" CR

A body that does not match its kind (a wrong echo, a malformed number, stray bytes) is
*garbled*: it is rejected and the command is sent again, up to ``retries`` more times; no value
is ever guessed. No prompt within ``timeout_s`` is a timeout, retried the same way. A port that
fails (unplugged USB adapter: the OS reports an error or end of file) is *lost*: no retry.
Status never raises: a failed exchange shows as ``fault=True`` with the reason, so a running
Bench stops with RunInterrupted (data kept, output driven to 0 V by the DAQ).
"""

from __future__ import annotations

import re
import threading
import time
from dataclasses import dataclass

from drivers.interfaces import AmplifierStatus, DriverError

try:
    import serial
except ImportError:  # pragma: no cover - pyserial is a core dependency of the transports
    serial = None

BAUDRATE = 115200
CR = b"\r"
PROMPT = b">"
NOT_DEFINED = b"CMD_NOT_DEFINED"
CHANNELS = ("x", "y", "z")
DEFAULT_CHANNEL_MAP = {"y": "x", "z": "y"}
_NUMBER = re.compile(rb"^\*\[\s*(-?\d+(?:\.\d+)?)\s*\]\r?\n?$")


@dataclass(frozen=True)
class Frame:
    """How one kind of command is answered; ``body`` is a regex for the bytes between echo and prompt."""

    kind: str
    body: re.Pattern


FRAME = {
    "query": Frame("query", _NUMBER),
    "id": Frame("id", re.compile(rb"^(?:[ -~]*\r\n?)+$")),
    "setter": Frame("setter", re.compile(rb"^\r?\n?$")),
}
QUERIES = {f"{c}{what}?" for c in CHANNELS for what in ("voltage", "min", "max")} | {"vlimit?"}


def frame_for(command: str) -> Frame:
    """The framing a command's reply follows (see the module table)."""
    if command == "id?":
        return FRAME["id"]
    if command in QUERIES:
        return FRAME["query"]
    if "=" in command:
        return FRAME["setter"]
    raise DriverError(f"MDT693B: {command!r} is not a command this driver sends")


class SerialLinkError(DriverError):
    """An exchange failed; ``kind`` is "timeout", "garbled", "refused" or "lost"."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind


class Mdt693b:
    """One controller on one serial port. Thread-safe; every exchange is one command and its prompt.

    ``port`` is a device path or any pyserial URL; ``link`` an already open serial-like object
    (tests). ``timeout_s`` bounds one attempt; ``retries`` extra attempts follow a timeout or a
    garbled reply."""

    def __init__(self, port: str | None = None, *, link=None, timeout_s: float = 0.2, retries: int = 2):
        if link is None:
            if serial is None:
                raise DriverError("pyserial is not installed: pip install pyserial")
            try:
                link = serial.serial_for_url(
                    port, baudrate=BAUDRATE, bytesize=8, parity="N", stopbits=1, timeout=0.01, write_timeout=timeout_s
                )
            except (OSError, ValueError, getattr(serial, "SerialException", OSError)) as exc:
                raise DriverError(f"MDT693B: cannot open serial port {port!r}: {exc}") from exc
        self.port = port or getattr(link, "port", "?")
        self.link = link
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.lost: str | None = None
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ exchanges
    def command(self, command: str) -> bytes:
        """Send one command; return its body (echo and prompt removed). Raises SerialLinkError."""
        frame = frame_for(command)
        with self._lock:
            if self.lost:
                raise SerialLinkError("lost", self.lost)
            last = None
            for _attempt in range(self.retries + 1):
                try:
                    raw = self._exchange(command)
                except SerialLinkError as exc:
                    if exc.kind == "lost":
                        self.lost = str(exc)
                        raise
                    last = exc
                    self._flush()
                    continue
                body = raw[: -len(PROMPT)]
                echo = command.encode() + CR
                if body.startswith(echo):
                    body = body[len(echo) :]
                if body.rstrip(b"\r\n") == NOT_DEFINED:
                    raise SerialLinkError("refused", f"MDT693B on {self.port}: {command!r} -> CMD_NOT_DEFINED")
                if frame.body.match(body):
                    return body
                last = SerialLinkError("garbled", f"MDT693B on {self.port}: garbled reply to {command!r}: {raw!r}")
                self._flush()
            raise SerialLinkError(last.kind, f"{last} ({self.retries + 1} attempts)")

    def query(self, command: str) -> float:
        """A numeric query (``xvoltage?``, ``vlimit?``, ...), in volts."""
        return float(FRAME["query"].body.match(self.command(command)).group(1))

    def set(self, name: str, *values: float) -> None:
        """A setter: ``set("xvoltage", 12.5)`` sends ``xvoltage=12.500``."""
        self.command(f"{name}=" + ",".join(f"{float(v):.3f}" for v in values))

    def identify(self) -> str:
        return self.command("id?").decode("ascii").replace("\r", "\n").strip()

    def close(self) -> None:
        try:
            self.link.close()
        except Exception:  # noqa: BLE001 - closing a lost port may itself fail
            pass

    def _exchange(self, command: str) -> bytes:
        try:
            self.link.reset_input_buffer()  # nothing unsolicited or late may pass for this command's reply
            self.link.write(command.encode("ascii") + CR)
            reply = bytearray()
            deadline = time.monotonic() + self.timeout_s
            while time.monotonic() < deadline:
                chunk = self.link.read(1)  # returns as soon as a byte arrives, then take what is waiting
                waiting = getattr(self.link, "in_waiting", 0)
                if chunk and waiting:
                    chunk += self.link.read(waiting)
                if chunk:
                    reply += chunk
                    if reply.endswith(PROMPT):
                        return bytes(reply)
        except Exception as exc:  # pyserial raises SerialException / OSError when the device goes away
            if isinstance(exc, SerialLinkError):
                raise
            raise SerialLinkError("lost", f"MDT693B: serial port {self.port} lost: {exc}") from exc
        raise SerialLinkError(
            "timeout",
            f"MDT693B on {self.port}: no reply to {command!r} within {self.timeout_s:g} s (got {bytes(reply)!r})",
        )

    def _flush(self) -> None:
        """Drop late bytes of a failed exchange so they cannot be read as the next reply."""
        try:
            time.sleep(0.005)
            self.link.reset_input_buffer()
        except Exception:  # noqa: BLE001 - a lost port shows on the next exchange
            pass


class SerialAmplifier:
    """One bench axis on one MDT693B channel (Amplifier protocol).

    ``gain_v_per_v`` is the modulation-input gain, ``output_limits_v`` is written to the
    controller as ``<ch>min=`` / ``<ch>max=`` and read back; slew, current and load describe the
    hardware and come from the bench configuration (the command set cannot report them)."""

    def __init__(
        self,
        controller: Mdt693b,
        axis: str,
        channel: str,
        *,
        gain_v_per_v: float,
        output_limits_v: tuple[float, float],
        slew_limit_v_per_s: float,
        current_limit_a: float,
        load_capacitance_f: float,
    ):
        if channel not in CHANNELS:
            raise DriverError(f"MDT693B channel must be one of {CHANNELS}, got {channel!r}")
        self.controller, self.axis, self.channel = controller, axis, channel
        self.gain_v_per_v = float(gain_v_per_v)
        self.slew_limit_v_per_s = float(slew_limit_v_per_s)
        self.current_limit_a = float(current_limit_a)
        self.load_capacitance_f = float(load_capacitance_f)
        self.output_limits_v = self.setup_limits(*output_limits_v)
        self._enabled = True

    def setup_limits(self, v_min_v: float, v_max_v: float) -> tuple[float, float]:
        """Write the channel's output limits (clipped to 0..vlimit), read them back, zero the set-point."""
        c = self.controller
        vlimit = c.query("vlimit?")
        lo, hi = max(0.0, float(v_min_v)), min(vlimit, float(v_max_v))
        if lo >= hi:
            raise DriverError(
                f"MDT693B {self.channel}: limits {v_min_v}..{v_max_v} V leave nothing within 0..{vlimit} V"
            )
        c.set(f"{self.channel}min", lo)
        c.set(f"{self.channel}max", hi)
        got = (c.query(f"{self.channel}min?"), c.query(f"{self.channel}max?"))
        if abs(got[0] - lo) > 0.05 or abs(got[1] - hi) > 0.05:
            raise DriverError(f"MDT693B {self.channel}: limits read back as {got}, wrote ({lo}, {hi})")
        c.set(f"{self.channel}voltage", 0.0)
        return got

    def set_voltage(self, volts_v: float) -> None:
        """Slow DC set-point of this channel (summed with the modulation input), in volts."""
        lo, hi = self.output_limits_v
        if not lo <= volts_v <= hi:
            raise DriverError(f"MDT693B {self.channel}: set-point {volts_v} V outside {lo}..{hi} V")
        self.controller.set(f"{self.channel}voltage", volts_v)

    def enable(self) -> None:
        self._enabled = True

    def disable(self) -> None:
        """Zero the DC set-point (the modulation input is zeroed by the DAQ)."""
        self.controller.set(f"{self.channel}voltage", 0.0)
        self._enabled = False

    def clear_fault(self) -> None:
        """A garbled or timed-out link recovers by itself; a lost port needs a new driver."""

    def status(self) -> AmplifierStatus:
        """Reads ``<ch>voltage?``. Never raises: a failed exchange is a fault naming the reason."""
        try:
            out = self.controller.query(f"{self.channel}voltage?")
        except DriverError as exc:
            return AmplifierStatus(
                enabled=self._enabled,
                fault=True,
                fault_reason=f"serial: {exc}",
                output_v=float("nan"),
                current_a=float("nan"),
                current_limited=False,
            )
        return AmplifierStatus(
            enabled=self._enabled,
            fault=False,
            fault_reason=None,
            output_v=out,
            current_a=float("nan"),
            current_limited=False,
        )


def open_amplifiers(
    port: str | None,
    axes_cfg: dict,
    *,
    channel_map: dict | None = None,
    link=None,
    timeout_s: float = 0.2,
    retries: int = 2,
) -> tuple[Mdt693b, dict[str, SerialAmplifier]]:
    """Open the controller and one SerialAmplifier per axis. ``axes_cfg[axis]`` holds gain_v_per_v,
    output_min_v, output_max_v, slew_limit_v_per_s, current_limit_a, load_capacitance_f."""
    ctl = Mdt693b(port, link=link, timeout_s=timeout_s, retries=retries)
    try:
        ctl.identify()
        mapping = {**DEFAULT_CHANNEL_MAP, **(channel_map or {})}
        amps = {
            axis: SerialAmplifier(
                ctl,
                axis,
                mapping[axis],
                gain_v_per_v=c["gain_v_per_v"],
                output_limits_v=(c["output_min_v"], c["output_max_v"]),
                slew_limit_v_per_s=c["slew_limit_v_per_s"],
                current_limit_a=c["current_limit_a"],
                load_capacitance_f=c["load_capacitance_f"],
            )
            for axis, c in axes_cfg.items()
        }
    except Exception:
        ctl.close()
        raise
    return ctl, amps
