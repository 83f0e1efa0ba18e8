"""MDT693B serial protocol, byte for byte: a scripted port (driver parsing, retries, errors) and
the emulator's responder on a real pseudo-terminal (what the wire carries)."""

from __future__ import annotations

import pytest
import serial

from drivers.emulated import World, load_config
from drivers.emulated import kernels as K
from drivers.emulated.wire import Mdt693bResponder
from drivers.serial_amplifier import Mdt693b, SerialLinkError, open_amplifiers


class ScriptedPort:
    """A serial-like object: records every write, answers each write with the next scripted reply
    (bytes, None for silence, or an exception to raise on read)."""

    def __init__(self, replies):
        self.replies, self.written, self._out = list(replies), [], b""
        self.port = "scripted"

    def write(self, data):
        self.written.append(bytes(data))
        reply = self.replies.pop(0) if self.replies else None
        self._out = reply

    def read(self, n):
        if isinstance(self._out, Exception):
            raise self._out
        out, self._out = (self._out or b"")[:n], (self._out or b"")[n:]
        return out

    def reset_input_buffer(self):
        self._out = b""

    def close(self):
        pass


def ctl(replies, **kw):
    port = ScriptedPort(replies)
    return Mdt693b(link=port, timeout_s=kw.pop("timeout_s", 0.05), **kw), port


def test_query_with_and_without_echo():
    c, port = ctl([b"xvoltage?\r*[  24.80]\r>", b"*[ 150.00]\r>"])
    assert c.query("xvoltage?") == 24.8
    assert c.query("vlimit?") == 150.0
    assert port.written == [b"xvoltage?\r", b"vlimit?\r"]


def test_setters_send_exact_bytes_and_accept_the_bare_prompt():
    c, port = ctl([b"xmin=0.000\r>", b"yvoltage=12.500\r>", b"xyzvoltage=1.000,2.000,3.000\r>"])
    c.set("xmin", 0)
    c.set("yvoltage", 12.5)
    c.set("xyzvoltage", 1, 2, 3)
    assert port.written == [b"xmin=0.000\r", b"yvoltage=12.500\r", b"xyzvoltage=1.000,2.000,3.000\r"]


def test_unknown_command_is_refused_without_retry():
    c, port = ctl([b"zmax=1.000\rCMD_NOT_DEFINED\r>"])
    with pytest.raises(SerialLinkError, match="CMD_NOT_DEFINED") as err:
        c.set("zmax", 1)
    assert err.value.kind == "refused" and port.written == [b"zmax=1.000\r"]


@pytest.mark.parametrize(
    "garbled",
    [b"xvoltage?\r*[ 2#.80]\r>", b"xvoltage?\r*[  24.80\r>", b"yvoltage?\r*[  24.80]\r>", b"xvoltage?\r24.80\r>"],
)
def test_garbled_replies_are_rejected_and_never_used(garbled):
    c, port = ctl([garbled] * 3)
    with pytest.raises(SerialLinkError, match="garbled") as err:
        c.query("xvoltage?")
    assert err.value.kind == "garbled" and port.written == [b"xvoltage?\r"] * 3  # 1 + 2 retries


def test_a_garbled_reply_is_retried_and_the_good_answer_used():
    c, port = ctl([b"xvoltage?\r*[ 2#.80]\r>", b"xvoltage?\r*[  31.25]\r>"])
    assert c.query("xvoltage?") == 31.25 and len(port.written) == 2


def test_timeout_is_retried_then_reported():
    c, port = ctl([None, b"xvoltage?\r*[  1", None], retries=2)
    with pytest.raises(SerialLinkError, match="no reply") as err:
        c.query("xvoltage?")
    assert err.value.kind == "timeout" and port.written == [b"xvoltage?\r"] * 3


def test_a_lost_port_fails_at_once_and_stays_lost():
    c, port = ctl([serial.SerialException("read failed: [Errno 5] Input/output error")])
    with pytest.raises(SerialLinkError, match="lost") as err:
        c.query("xvoltage?")
    assert err.value.kind == "lost" and len(port.written) == 1
    with pytest.raises(SerialLinkError, match="lost"):
        c.query("vlimit?")
    assert len(port.written) == 1  # nothing more is sent to a lost port


def _world():
    cfg = load_config("base", {"axes.*.amplifier.noise.enabled": False})
    return World(cfg, 0)


def test_emulator_on_a_pty_transcript_of_the_set_up():
    world = _world()
    responder = Mdt693bResponder(world, {"x": "y", "y": "z"})
    try:
        axes = {ax: world.config["axes"][ax]["amplifier"] for ax in ("y", "z")}
        controller, amps = open_amplifiers(responder.port, axes)
        assert amps["y"].output_limits_v == (0.0, 150.0) and amps["y"].channel == "x" and amps["z"].channel == "y"
        expected = [(b"id?", b"id?\rModel MDT693B (emulated)\rSerial#: EMU00001\rFirmware Version: 1.09\r>")]
        for ch in "xy":
            expected += [
                (b"vlimit?", b"vlimit?\r*[ 150.00]\r>"),
                (ch.encode() + b"min=0.000", ch.encode() + b"min=0.000\r>"),
                (ch.encode() + b"max=150.000", ch.encode() + b"max=150.000\r>"),
                (ch.encode() + b"min?", ch.encode() + b"min?\r*[   0.00]\r>"),
                (ch.encode() + b"max?", ch.encode() + b"max?\r*[ 150.00]\r>"),
                (ch.encode() + b"voltage=0.000", ch.encode() + b"voltage=0.000\r>"),
            ]
        assert responder.transcript == expected
        # limits reach the world's output clamp; set-points are stored; status reads the output
        amps["z"].setup_limits(0, 100)
        assert responder.limits_v["y"] == [0.0, 100.0] and world.pa[1, K.A_VMAX_V] == 100.0
        controller.set("xyzvoltage", 1, 2, 3)
        assert responder.setpoint_v == {"x": 1.0, "y": 2.0, "z": 3.0}
        assert amps["y"].status().output_v == 0.0 and not amps["y"].status().fault
        assert responder.transcript[-1] == (b"xvoltage?", b"xvoltage?\r*[   0.00]\r>")
        link = controller.link
        link.write(b"bogus\r")
        reply = b""
        while not reply.endswith(b">"):
            reply += link.read(64)
        assert reply == b"bogus\rCMD_NOT_DEFINED\r>"
        controller.close()
    finally:
        responder.close()


def test_emulator_faults_reach_the_driver_as_reasons():
    responder = Mdt693bResponder(_world())
    try:
        c = Mdt693b(responder.port, timeout_s=0.1, retries=1)
        responder.mode = "garble"
        with pytest.raises(SerialLinkError, match=r"garbled reply to 'xvoltage\?': b'xvoltage\?\\r\*\[ 2#\.\?"):
            c.query("xvoltage?")
        responder.mode = "silent"
        with pytest.raises(SerialLinkError, match="no reply"):
            c.query("xvoltage?")
        responder.mode = "ok"
        assert c.query("vlimit?") == 150.0
        responder.unplug()
        with pytest.raises(SerialLinkError, match="lost"):
            c.query("vlimit?")
        c.close()
    finally:
        responder.close()
