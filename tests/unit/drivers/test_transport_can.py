"""CANopen-style gauge protocol, byte for byte on a python-can virtual bus: SDO, SYNC → TPDO
bursts, EMCY, and the driver's handling of aborts, lost frames, timeouts and bus-off."""

from __future__ import annotations

import struct
import types
import uuid

import can
import numpy as np
import pytest

from drivers.can_sensor import CanDisplacementSensor, CanGaugeBus
from drivers.emulated import World, load_config
from drivers.emulated.wire import EmulatedGaugeNodes
from drivers.interfaces import DriverError


class Sniffer:
    """A third node on the bus that records every frame as (COB-ID, data bytes)."""

    def __init__(self, channel):
        self.bus = can.Bus(interface="virtual", channel=channel)

    def frames(self):
        out = []
        while (msg := self.bus.recv(0.05)) is not None:
            out.append((msg.arbitration_id, bytes(msg.data)))
        return out


@pytest.fixture
def wire():
    channel = f"test-{uuid.uuid4().hex[:8]}"
    world = World(load_config("base"), 0)
    sniffer = Sniffer(channel)
    nodes = EmulatedGaugeNodes(world, {"y": 1, "z": 2}, channel=channel)
    host = CanGaugeBus({"y": 1, "z": 2}, channel=channel, timeout_s=0.3)
    yield world, nodes, host, sniffer
    host.close()
    nodes.close()
    sniffer.bus.shutdown()


def test_sdo_write_read_and_aborts_byte_for_byte(wire):
    world, nodes, host, sniffer = wire
    host.sdo_write("y", "resolution_nm", 5)
    assert host.sdo_read("y", "resolution_nm") == 5
    host.sdo_write("z", "filter_hz", 1000)
    assert host.sdo_read("z", "filter_hz") == 1000
    assert host.sdo_read("y", "error_register") == 0
    assert host.sdo_read("z", "range_nm") == 20_000  # ±10 V × 2 µm/V
    assert sniffer.frames() == [
        (0x601, bytes.fromhex("23 00 20 00 05 00 00 00")),
        (0x581, bytes.fromhex("60 00 20 00 00 00 00 00")),
        (0x601, bytes.fromhex("40 00 20 00 00 00 00 00")),
        (0x581, bytes.fromhex("43 00 20 00 05 00 00 00")),
        (0x602, bytes.fromhex("2B 02 20 00 E8 03 00 00")),
        (0x582, bytes.fromhex("60 02 20 00 00 00 00 00")),
        (0x602, bytes.fromhex("40 02 20 00 00 00 00 00")),
        (0x582, bytes.fromhex("4B 02 20 00 E8 03 00 00")),
        (0x601, bytes.fromhex("40 01 10 00 00 00 00 00")),
        (0x581, bytes.fromhex("4F 01 10 00 00 00 00 00")),
        (0x602, bytes.fromhex("40 03 20 00 00 00 00 00")),
        (0x582, bytes.fromhex("43 03 20 00 20 4E 00 00")),
    ]
    with pytest.raises(DriverError, match=r"SDO abort 0x06010002 \(attempt to write a read-only object\) on 0x2003:00"):
        host.sdo_write("y", "range_nm", 1)
    with pytest.raises(DriverError, match=r"SDO abort 0x06090030 \(value range exceeded\) on 0x2000:00"):
        host.sdo_write("y", "resolution_nm", 5000)
    assert sniffer.frames()[-1] == (0x581, bytes.fromhex("80 00 20 00 30 00 09 06"))
    host._send(0x601, bytes.fromhex("40 07 20 00 00 00 00 00"))  # an object that does not exist
    assert sniffer.frames() == [
        (0x601, bytes.fromhex("40 07 20 00 00 00 00 00")),
        (0x581, bytes.fromhex("80 07 20 00 00 00 02 06")),
    ]


def test_sync_releases_one_tpdo_per_sample_in_order(wire):
    world, nodes, host, sniffer = wire
    sensors = {ax: CanDisplacementSensor(host, ax) for ax in ("y", "z")}
    sniffer.frames()
    nodes.capture({"y": np.array([1.2344, -0.0005, 9.9996]), "z": np.array([-3.0, 0.0014, 19.5])})
    got = host.sync_read(3)
    np.testing.assert_allclose(got["y"], [1.234, -0.000, 10.000])
    np.testing.assert_allclose(got["z"], [-3.0, 0.001, 19.5])
    frames = sniffer.frames()
    assert frames[0] == (0x080, b"")
    assert frames[1:4] == [
        (0x181, struct.pack("<iBH", 1234, 0, 0)),
        (0x181, bytes.fromhex("00 00 00 00 00 01 00")),
        (0x181, bytes.fromhex("10 27 00 00 00 02 00")),
    ]
    assert frames[4:] == [(0x182, struct.pack("<iBH", v, 0, k)) for k, v in enumerate((-3000, 1, 19500))]
    assert all(s.status().ok for s in sensors.values()) and sensors["z"].range_um == (-20.0, 20.0)


def test_a_dropout_sends_emcy_and_flags_the_status(wire):
    world, nodes, host, sniffer = wire
    sensor = CanDisplacementSensor(host, "y")
    sniffer.frames()
    world.inject_fault("sensor_dropout", "y")
    nodes.capture({"y": np.zeros(2), "z": np.zeros(2)})
    host.sync_read(2)
    frames = sniffer.frames()
    assert (0x081, bytes.fromhex("00 73 01 01 00 00 00 00")) in frames
    assert (0x181, bytes.fromhex("00 00 00 00 01 00 00")) in frames
    assert host.emergencies[0] == ("y", 0x7300, 0x01)
    status = sensor.status()
    assert not status.ok and "dropout" in status.reason and "CAN node 1" in status.reason


def test_timeout_names_what_was_missing(wire):
    world, nodes, host, sniffer = wire
    nodes.inject("silent")
    with pytest.raises(DriverError, match=r"timeout after 0.3 s waiting for SDO response from node 1"):
        host.sdo_read("y", "resolution_nm")
    nodes.clear()
    nodes.capture({"y": np.zeros(4), "z": np.zeros(4)})
    with pytest.raises(DriverError, match=r"TPDO burst \(got 4 of 5 from node 1, 4 of 5 from node 2\)"):
        host.sync_read(5)
    nodes.capture({"y": np.zeros(1), "z": np.zeros(1)})
    with pytest.raises(DriverError, match="positions no longer align"):  # latched: stale frames are never used
        host.sync_read(1)
    assert not CanDisplacementSensor.status(types.SimpleNamespace(bus=host, axis="y", node_id=1)).ok


def test_bus_off_error_frame_latches_a_failure(wire):
    world, nodes, host, sniffer = wire
    sensor = CanDisplacementSensor(host, "z")
    nodes.bus.send(can.Message(arbitration_id=0x020, is_error_frame=True, data=bytes(8)))  # no ACK: noted only
    nodes.capture({"y": np.zeros(1), "z": np.zeros(1)})
    assert host.sync_read(1)["z"][0] == 0.0 and sensor.status().ok
    assert host.emergencies == [("error_frame", 0x020, "no ACK on transmission")]
    nodes.inject("bus_off")
    nodes.capture({"y": np.zeros(1), "z": np.zeros(1)})
    with pytest.raises(DriverError, match="bus-off"):
        host.sync_read(1)
    assert not sensor.status().ok and "bus-off" in sensor.status().reason
    with pytest.raises(DriverError, match="bus-off"):
        host.sync_read(1)  # latched: nothing more is sent


def test_lost_and_malformed_tpdos_are_rejected():
    channel = f"test-{uuid.uuid4().hex[:8]}"
    node = can.Bus(interface="virtual", channel=channel)
    host = CanGaugeBus({"y": 1}, channel=channel, timeout_s=0.2)
    try:
        for seq in (0, 2):  # frame 1 never arrives
            node.send(can.Message(arbitration_id=0x181, data=struct.pack("<iBH", 7, 0, seq), is_extended_id=False))
        with pytest.raises(DriverError, match="TPDO sequence 2, expected 1: frames lost"):
            host.sync_read(2)
        host.failure = None
        node.send(can.Message(arbitration_id=0x181, data=b"\x01\x02", is_extended_id=False))
        with pytest.raises(DriverError, match="TPDO of 2 bytes"):
            host.sync_read(1)
    finally:
        host.close()
        node.shutdown()
