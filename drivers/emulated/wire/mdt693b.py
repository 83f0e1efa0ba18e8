"""The emulated MDT693B on a pseudo-terminal: a responder thread speaking the serial protocol.

``Mdt693bResponder(world)`` opens a pty pair (os.openpty); ``port`` is the slave's device path,
which any serial program (pyserial included) opens like a USB adapter. Framing as in
drivers/serial_amplifier.py: commands end in CR; the reply is the echo + CR, a body, and ``>``.

World binding: ``<ch>voltage?`` answers the mapped axis's amplifier output (volts at the
actuator, 2 decimals); ``<ch>min=`` / ``<ch>max=`` set the world's output clamp; ``<ch>voltage=``
is a DC set-point that ``WireDaq`` sums into the modulation path. Faults for tests:
``mode = "garble" | "silent"`` and ``unplug()`` (closes the master side: the port reads EIO).
``transcript`` holds every (received command, reply) pair as bytes.
"""

from __future__ import annotations

import os
import re
import select
import threading
import tty

from drivers.emulated import kernels as K

ID_TEXT = b"Model MDT693B (emulated)\rSerial#: EMU00001\rFirmware Version: 1.09\r"
_SET = re.compile(r"^([xyz])(voltage|min|max)=(-?\d+(?:\.\d*)?)$")
_SET3 = re.compile(r"^xyzvoltage=(-?[\d.]+),(-?[\d.]+),(-?[\d.]+)$")
_GET = re.compile(r"^([xyz])(voltage|min|max)\?$")


class Mdt693bResponder:
    """A three-channel controller whose channels ``channel_axis`` (e.g. {"x": "y", "y": "z"}) drive world axes."""

    def __init__(self, world, channel_axis: dict[str, str] | None = None, vlimit_v: float = 150.0):
        self.world = world
        self.channel_axis = channel_axis or {"x": "y", "y": "z"}
        self.vlimit_v = float(vlimit_v)
        self.setpoint_v = {c: 0.0 for c in "xyz"}
        self.limits_v = {c: [0.0, self.vlimit_v] for c in "xyz"}
        self.echo = True
        self.mode = "ok"
        self.transcript: list[tuple[bytes, bytes]] = []
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="mdt693b-emulator", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ protocol
    def reply_to(self, command: bytes) -> bytes:
        """The full reply (echo, body, prompt) to one command without its CR."""
        text = command.decode("ascii", "replace")
        body = self._body(text)
        echo = command + b"\r" if self.echo else b""
        if self.mode == "garble" and body.startswith(b"*["):
            body = b"*[ 2#.?" + body[7:]
        return echo + body + b">"

    def _body(self, text: str) -> bytes:
        if text == "id?":
            return ID_TEXT
        if text == "vlimit?":
            return self._number(self.vlimit_v)
        if text in ("echo=0", "echo=1"):
            self.echo = text.endswith("1")
            return b""
        m = _GET.match(text)
        if m:
            ch, what = m.groups()
            if what == "voltage":
                return self._number(self._output_v(ch))
            return self._number(self.limits_v[ch][0 if what == "min" else 1])
        m = _SET.match(text)
        if m:
            ch, what, value = m.group(1), m.group(2), float(m.group(3))
            self._set(ch, what, value)
            return b""
        m = _SET3.match(text)
        if m:
            for ch, value in zip("xyz", m.groups()):
                self._set(ch, "voltage", float(value))
            return b""
        return b"CMD_NOT_DEFINED\r"

    @staticmethod
    def _number(value: float) -> bytes:
        return b"*[%7.2f]\r" % value

    def _set(self, ch: str, what: str, value: float) -> None:
        lo, hi = self.limits_v[ch]
        if what == "voltage":
            self.setpoint_v[ch] = min(max(value, lo), hi)
            return
        value = min(max(value, 0.0), self.vlimit_v)
        self.limits_v[ch][0 if what == "min" else 1] = value
        axis = self.channel_axis.get(ch)
        if axis is not None:
            a = self.world.axis_index(axis)
            self.world.pa[a, K.A_VMIN_V if what == "min" else K.A_VMAX_V] = value

    def _output_v(self, ch: str) -> float:
        axis = self.channel_axis.get(ch)
        if axis is None:
            return self.setpoint_v[ch]
        return float(self.world.sa[self.world.axis_index(axis), K.S_VP])

    # ------------------------------------------------------------------ transport
    def _serve(self) -> None:
        pending = b""
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._master], [], [], 0.05)
                if not ready:
                    continue
                data = os.read(self._master, 256)
            except OSError:
                return
            if not data:
                return
            pending += data
            while b"\r" in pending:
                command, pending = pending.split(b"\r", 1)
                command = command.strip(b"\n")
                if self.mode == "silent":
                    self.transcript.append((command, b""))
                    continue
                reply = self.reply_to(command)
                self.transcript.append((command, reply))
                try:
                    os.write(self._master, reply)
                except OSError:
                    return

    def unplug(self) -> None:
        """Pull the cable: the master side closes and the port fails with an I/O error."""
        self._stop.set()
        self._thread.join(timeout=1.0)
        for fd in (self._master,):
            try:
                os.close(fd)
            except OSError:
                pass
        self._master = -1

    def close(self) -> None:
        if self._master != -1:
            self.unplug()
        try:
            os.close(self._slave)
        except OSError:
            pass
        self._slave = -1
