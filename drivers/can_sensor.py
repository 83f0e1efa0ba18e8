"""Displacement gauges as CANopen-style nodes on a CAN bus (python-can).

Frames (11-bit identifiers, node id n = 1..127, integers little-endian)::

    SYNC   0x080        host → all, no data: every node sends the samples taken since the last SYNC
    TPDO   0x180 + n    node → host, 7 bytes "<iBH": position (int32, nm), status (u8), sequence (u16)
                        status bit 0 = gauge signal lost (dropout), bit 1 = saturated
                        sequence counts TPDOs modulo 65536: a gap means frames were lost
    EMCY   0x080 + n    node → host, 8 bytes "<HBB4x": error code (0x7300 sensor), error register, status
    SDO    0x600 + n    host → node request; 0x580 + n node → host response (expedited only)
                        byte 0 command specifier, 1–2 index, 3 sub-index, 4–7 data
                        0x40 read → 0x4F / 0x4B / 0x43 (1 / 2 / 4 data bytes)
                        0x2F / 0x2B / 0x23 write 1 / 2 / 4 bytes → 0x60 ack
                        0x80 abort, data = abort code (u32)

Object dictionary ``OD`` (index, sub-index → name, size in bytes, writable, range)::

    0x1000:00 device_type  u32 ro    0x2000:00 resolution_nm u32 rw 1..1000 (position LSB)
    0x1001:00 error_register u8 ro   0x2001:00 scale_ppm     u32 rw (calibration gain, 1e6 = 1)
    0x2003:00 range_nm u32 ro (±)    0x2002:00 filter_hz     u16 rw 0..50000 (one-pole low-pass, 0 = off)

Data path (``positions = "can"``): one SYNC per DAQ block; each node answers with a burst of one TPDO per sample it took
on the DAQ's exported sample clock since the previous SYNC (the sensor buffers; the bus then
carries every sample, not a decimated subset). With ``positions = "ai"`` the gauges' analog outputs
go to the DAQ's AI and the bus carries configuration, EMCY and error frames only. Errors: an SDO abort, no frame within
``timeout_s``, a sequence gap, an error frame saying bus-off, or a failing transmit raise
DriverError naming the node and the cause; bus-off and lost frames also latch the sensor status.
"""

from __future__ import annotations

import struct
import time

import numpy as np

from drivers.interfaces import DriverError, SensorStatus

try:
    import can
except ImportError:  # pragma: no cover - python-can is needed only for this transport
    can = None

COB_SYNC, COB_EMCY, COB_TPDO, COB_SDO_TX, COB_SDO_RX = 0x080, 0x080, 0x180, 0x580, 0x600
TPDO_FORMAT = "<iBH"
STATUS_DROPOUT, STATUS_SATURATED = 0x01, 0x02
EMCY_SENSOR = 0x7300
CAN_ERR_BUSOFF = 0x040  # SocketCAN error class bits carried in an error frame's identifier
CAN_ERR_CLASSES = {
    0x001: "TX timeout",
    0x002: "arbitration lost",
    0x004: "controller problem",
    0x008: "protocol violation",
    0x010: "transceiver status",
    0x020: "no ACK on transmission",
    0x040: "bus-off",
    0x080: "bus error",
    0x100: "controller restarted",
}
OD = {
    (0x1000, 0): ("device_type", 4, False, 0, 2**32 - 1),
    (0x1001, 0): ("error_register", 1, False, 0, 255),
    (0x2000, 0): ("resolution_nm", 4, True, 1, 1000),
    (0x2001, 0): ("scale_ppm", 4, True, 500_000, 2_000_000),
    (0x2002, 0): ("filter_hz", 2, True, 0, 50_000),
    (0x2003, 0): ("range_nm", 4, False, 1, 2**31 - 1),
}
OD_INDEX = {entry[0]: key for key, entry in OD.items()}
SDO_ABORTS = {
    0x05040000: "SDO protocol timed out",
    0x05040001: "command specifier not valid",
    0x06010002: "attempt to write a read-only object",
    0x06020000: "object does not exist",
    0x06070010: "data type length mismatch",
    0x06090030: "value range exceeded",
}


def sdo_size_cs(size: int, *, read: bool) -> int:
    """Expedited command specifier for a 1/2/4-byte value: read response 0x4F/0x4B/0x43, write 0x2F/0x2B/0x23."""
    return (0x43 if read else 0x23) | ((4 - size) << 2)


def sdo_abort(index: int, sub: int, code: int) -> bytes:
    return bytes([0x80]) + index.to_bytes(2, "little") + bytes([sub]) + code.to_bytes(4, "little")


class CanGaugeBus:
    """The host side of one CAN bus carrying gauge nodes ``{axis: node_id}``; not thread-safe."""

    def __init__(
        self,
        node_ids: dict[str, int],
        *,
        interface: str = "virtual",
        channel: str = "evc",
        bus=None,
        timeout_s: float = 0.5,
        bitrate: int | None = None,
    ):
        if bus is None:
            if can is None:
                raise DriverError("python-can is not installed: pip install python-can")
            kwargs = {"bitrate": bitrate} if bitrate else {}
            try:
                bus = can.Bus(interface=interface, channel=channel, **kwargs)
            except Exception as exc:  # noqa: BLE001 - python-can raises many kinds here
                raise DriverError(f"CAN: cannot open {interface}:{channel}: {exc}") from exc
        self.bus, self.where = bus, f"{interface}:{channel}"
        self.node_ids = {axis: int(n) for axis, n in node_ids.items()}
        for axis, n in self.node_ids.items():
            if not 1 <= n <= 127:
                raise DriverError(f"CAN node id for {axis} must be 1..127, got {n}")
        self.timeout_s = float(timeout_s)
        self.failure: str | None = None
        self.node_status = {axis: 0 for axis in self.node_ids}
        self.emergencies: list[tuple[str, int, int]] = []
        self._seq = {axis: None for axis in self.node_ids}
        self._axis_by_tpdo = {COB_TPDO + n: axis for axis, n in self.node_ids.items()}
        self._axis_by_emcy = {COB_EMCY + n: axis for axis, n in self.node_ids.items()}

    # ------------------------------------------------------------------ SDO
    def sdo_read(self, axis: str, name: str) -> int:
        index, sub = OD_INDEX[name]
        data = self._sdo(axis, bytes([0x40]) + index.to_bytes(2, "little") + bytes([sub, 0, 0, 0, 0]))
        size = {0x4F: 1, 0x4B: 2, 0x43: 4}.get(data[0])
        if size is None:
            raise DriverError(f"CAN node {self.node_ids[axis]}: bad SDO read response {data.hex(' ')}")
        return int.from_bytes(data[4 : 4 + size], "little")

    def sdo_write(self, axis: str, name: str, value: int) -> None:
        index, sub = OD_INDEX[name]
        size = OD[(index, sub)][1]
        payload = int(value).to_bytes(size, "little") + bytes(4 - size)
        data = self._sdo(
            axis, bytes([sdo_size_cs(size, read=False)]) + index.to_bytes(2, "little") + bytes([sub]) + payload
        )
        if data[0] != 0x60:
            raise DriverError(f"CAN node {self.node_ids[axis]}: bad SDO write response {data.hex(' ')}")

    def _sdo(self, axis: str, request: bytes) -> bytes:
        node = self.node_ids[axis]
        self._send(COB_SDO_RX + node, request)
        deadline = time.monotonic() + self.timeout_s
        while True:
            msg = self._recv(deadline, f"SDO response from node {node}")
            if msg.arbitration_id != COB_SDO_TX + node or len(msg.data) != 8:
                continue
            data = bytes(msg.data)
            if data[1:4] != request[1:4]:
                raise DriverError(f"CAN node {node}: SDO response for the wrong object: {data.hex(' ')}")
            if data[0] == 0x80:
                code = int.from_bytes(data[4:8], "little")
                why = SDO_ABORTS.get(code, "unknown abort code")
                raise DriverError(
                    f"CAN node {node}: SDO abort 0x{code:08X} ({why}) on "
                    f"0x{int.from_bytes(data[1:3], 'little'):04X}:{data[3]:02X}"
                )
            return data

    # ------------------------------------------------------------------ SYNC / TPDO
    def sync_read(self, n: int) -> dict[str, np.ndarray]:
        """Send SYNC; collect the n samples per node it releases. Returns positions in µm per axis."""
        if self.failure:
            raise DriverError(self.failure)
        try:
            return self._sync_read(n)
        except DriverError as exc:  # a burst cut short leaves frames in flight: positions would misalign
            self.failure = self.failure or f"{exc}; positions no longer align with the DAQ blocks, reopen the bench"
            raise DriverError(self.failure) from exc

    def _sync_read(self, n: int) -> dict[str, np.ndarray]:
        self._send(COB_SYNC, b"")
        got = {axis: np.empty(n) for axis in self.node_ids}
        count = {axis: 0 for axis in self.node_ids}
        remaining = n * len(self.node_ids)
        while remaining:
            deadline = time.monotonic() + self.timeout_s
            msg = self._recv(
                deadline,
                "TPDO burst (got "
                + ", ".join(f"{count[a]} of {n} from node {self.node_ids[a]}" for a in self.node_ids)
                + ")",
            )
            axis = self._axis_by_tpdo.get(msg.arbitration_id)
            if axis is None or count[axis] >= n:
                continue
            if len(msg.data) != struct.calcsize(TPDO_FORMAT):
                self._fail(
                    f"CAN node {self.node_ids[axis]}: TPDO of {len(msg.data)} bytes, expected 7: "
                    f"{bytes(msg.data).hex(' ')}"
                )
            pos_nm, status, seq = struct.unpack(TPDO_FORMAT, bytes(msg.data))
            expected = self._seq[axis]
            if expected is not None and seq != expected:
                self._fail(f"CAN node {self.node_ids[axis]}: TPDO sequence {seq}, expected {expected}: frames lost")
            self._seq[axis] = (seq + 1) & 0xFFFF
            self.node_status[axis] = status
            got[axis][count[axis]] = pos_nm * 1e-3
            count[axis] += 1
            remaining -= 1
        return got

    # ------------------------------------------------------------------ low level
    def _send(self, cob: int, data: bytes) -> None:
        if self.failure:
            raise DriverError(self.failure)
        try:
            self.bus.send(can.Message(arbitration_id=cob, data=data, is_extended_id=False))
        except Exception as exc:  # noqa: BLE001 - can.CanError, OSError on a downed interface
            self._fail(f"CAN {self.where}: transmit of 0x{cob:03X} failed: {exc}")

    def poll(self) -> None:
        """Handle every frame already received (EMCY, error frames) without waiting; bus-off raises."""
        while True:
            try:
                msg = self.bus.recv(0)
            except Exception as exc:  # noqa: BLE001
                self._fail(f"CAN {self.where}: receive failed: {exc}")
            if msg is None:
                return
            self._handle(msg)

    def _recv(self, deadline: float, waiting_for: str):
        """Next data frame; error frames and EMCY are handled here. Raises on timeout or bus-off."""
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise DriverError(f"CAN {self.where}: timeout after {self.timeout_s:g} s waiting for {waiting_for}")
            try:
                msg = self.bus.recv(left)
            except Exception as exc:  # noqa: BLE001
                self._fail(f"CAN {self.where}: receive failed: {exc}")
            if msg is not None and self._handle(msg) is not None:
                return msg

    def _handle(self, msg):
        """The frame if it is data for the caller; None after handling an error frame or an EMCY."""
        if msg.is_error_frame:
            classes = [name for bit, name in CAN_ERR_CLASSES.items() if msg.arbitration_id & bit]
            if msg.arbitration_id & CAN_ERR_BUSOFF:
                self._fail(f"CAN {self.where}: bus-off (error frame 0x{msg.arbitration_id:X})")
            self.emergencies.append(("error_frame", msg.arbitration_id, ", ".join(classes) or "unknown"))
            return None
        axis = self._axis_by_emcy.get(msg.arbitration_id)
        if axis is not None and len(msg.data) >= 4:
            code, register, status = struct.unpack_from("<HBB", bytes(msg.data))
            self.emergencies.append((axis, code, register))
            self.node_status[axis] |= status
            return None
        return msg

    def _fail(self, reason: str):
        self.failure = reason
        raise DriverError(reason)

    def close(self) -> None:
        try:
            self.bus.shutdown()
        except Exception:  # noqa: BLE001
            pass


class CanDisplacementSensor:
    """One gauge node as a DisplacementSensor. ``scale_um_per_v`` is nominal (range / 10 V):
    readings arrive in nm; the composed DAQ presents them to the Bench as volts on that scale."""

    def __init__(
        self, bus: CanGaugeBus, axis: str, *, resolution_nm: int = 1, filter_hz: int = 0, scale_ppm: int = 1_000_000
    ):
        self.bus, self.axis = bus, axis
        self.node_id = bus.node_ids[axis]
        bus.sdo_write(axis, "resolution_nm", resolution_nm)
        bus.sdo_write(axis, "filter_hz", filter_hz)
        bus.sdo_write(axis, "scale_ppm", scale_ppm)
        got = (bus.sdo_read(axis, "resolution_nm"), bus.sdo_read(axis, "filter_hz"), bus.sdo_read(axis, "scale_ppm"))
        if got != (resolution_nm, filter_hz, scale_ppm):
            raise DriverError(f"CAN node {self.node_id}: configuration read back as {got}")
        span_um = bus.sdo_read(axis, "range_nm") * 1e-3
        self.range_um = (-span_um, span_um)
        self.scale_um_per_v = span_um / 10.0

    def status(self) -> SensorStatus:
        if self.bus.failure:
            return SensorStatus(ok=False, saturated=False, reason=f"gauge {self.axis}: {self.bus.failure}")
        s = self.bus.node_status[self.axis]
        if s & STATUS_DROPOUT:
            return SensorStatus(
                ok=False, saturated=False, reason=f"gauge {self.axis} (CAN node {self.node_id}): dropout, signal lost"
            )
        if s & STATUS_SATURATED:
            return SensorStatus(
                ok=False, saturated=True, reason=f"gauge {self.axis} (CAN node {self.node_id}): saturated"
            )
        return SensorStatus(ok=True, saturated=False, reason=None)
