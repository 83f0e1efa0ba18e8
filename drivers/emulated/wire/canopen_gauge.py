"""Emulated capacitance gauges as CANopen nodes on a python-can bus (virtual, or vcan where present).

One thread serves every node on one bus. Per node (id n), see drivers/can_sensor.py for the layout
(with ``stream=False`` positions stay on the DAQ's AI and the bus carries SDO, EMCY and errors only):
- SYNC (0x080, no data) → a burst of TPDOs (0x180+n), one per sample captured since the last SYNC;
- SDO server (request 0x600+n, response 0x580+n), object dictionary ``OD``;
- EMCY (0x080+n) once when the gauge drops out or saturates;
- test faults: ``inject("bus_off")`` sends a bus-off error frame and goes silent, ``inject("silent")``
  only goes silent; ``clear()`` recovers.

Samples reach a node through ``capture``: the wire DAQ hands over each block's gauge readings
(µm, as the gauge's ADC saw them on the shared sample clock) before the driver's SYNC.
"""

from __future__ import annotations

import struct
import threading
from collections import deque

import numpy as np

from drivers.can_sensor import (
    CAN_ERR_BUSOFF,
    COB_EMCY,
    COB_SDO_RX,
    COB_SDO_TX,
    COB_SYNC,
    COB_TPDO,
    EMCY_SENSOR,
    OD,
    STATUS_DROPOUT,
    STATUS_SATURATED,
    TPDO_FORMAT,
    sdo_abort,
    sdo_size_cs,
)
from drivers.emulated import kernels as K

try:
    import can
except ImportError:  # pragma: no cover
    can = None


class _Node:
    def __init__(self, axis: str, node_id: int, range_nm: int):
        self.axis, self.node_id = axis, node_id
        self.values = {
            "device_type": 0x00020194,
            "error_register": 0,
            "resolution_nm": 1,
            "scale_ppm": 1_000_000,
            "filter_hz": 0,
            "range_nm": range_nm,
        }
        self.buffer: deque[tuple[np.ndarray, int]] = deque()
        self.seq = 0
        self.filtered = None
        self.emcy_sent = False


class EmulatedGaugeNodes:
    """CANopen gauge nodes ``{axis: node_id}`` bound to a World, on ``can.Bus(interface, channel)``."""

    def __init__(
        self, world, node_ids: dict[str, int], interface: str = "virtual", channel: str = "evc", stream: bool = True
    ):
        if can is None:
            raise RuntimeError("python-can is not installed")
        self.world, self.stream = world, stream  # stream False: positions go to the DAQ's AI, not the bus
        self.bus = can.Bus(interface=interface, channel=channel)
        self.nodes = {}
        for axis, nid in node_ids.items():
            scale = world.config["axes"][axis]["gauge"]["scale_um_per_v"]
            self.nodes[axis] = _Node(axis, int(nid), int(round(world.range_v * scale * 1000)))
        self._by_id = {n.node_id: n for n in self.nodes.values()}
        self.fault: str | None = None
        self.sample_rate_hz = world.sample_rate_hz
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="can-gauge-emulator", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ data in
    def capture(self, x_um: dict[str, np.ndarray]) -> None:
        """Queue one block of gauge readings per axis (µm) with the gauge status at the block's end."""
        with self._lock:
            self.sample_rate_hz = self.world.sample_rate_hz
            for axis, node in self.nodes.items():
                sa = self.world.sa[self.world.axis_index(axis)]
                status = (STATUS_DROPOUT if sa[K.S_DROP] > 0.5 else 0) | (
                    STATUS_SATURATED if sa[K.S_SAT] > 0.5 or sa[K.S_SATN] > 0 else 0
                )
                if self.stream:
                    node.buffer.append((np.asarray(x_um[axis], dtype=float).copy(), status))
                elif status and not self.fault:
                    self._emcy(node, status)

    def inject(self, kind: str) -> None:
        if kind not in ("bus_off", "silent"):
            raise ValueError(f"unknown CAN fault {kind!r}")
        self.fault = kind
        if kind == "bus_off":
            self.bus.send(
                can.Message(arbitration_id=CAN_ERR_BUSOFF, is_error_frame=True, is_extended_id=False, data=bytes(8))
            )

    def clear(self) -> None:
        self.fault = None

    # ------------------------------------------------------------------ serving
    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(0.05)
            except Exception:  # noqa: BLE001 - bus shut down
                return
            if msg is None or msg.is_error_frame or self.fault:
                continue
            cob = msg.arbitration_id
            if cob == COB_SYNC:
                self._burst()
            elif COB_SDO_RX < cob <= COB_SDO_RX + 0x7F and (cob - COB_SDO_RX) in self._by_id:
                self._sdo(self._by_id[cob - COB_SDO_RX], bytes(msg.data))

    def _send(self, cob: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=cob, data=data, is_extended_id=False))

    def _burst(self) -> None:
        with self._lock:
            blocks = {axis: list(node.buffer) for axis, node in self.nodes.items()}
            for node in self.nodes.values():
                node.buffer.clear()
        for axis, node in self.nodes.items():
            for x_um, status in blocks[axis]:
                if status:
                    self._emcy(node, status)
                for nm in self._reported_nm(node, x_um):
                    self._send(COB_TPDO + node.node_id, struct.pack(TPDO_FORMAT, int(nm), status, node.seq))
                    node.seq = (node.seq + 1) & 0xFFFF

    def _emcy(self, node: _Node, status: int) -> None:
        """One EMCY per fault episode: error code 0x7300 (sensor), error register 0x01 (generic), status."""
        if not node.emcy_sent:
            node.emcy_sent = True
            node.values["error_register"] = 0x01
            self._send(COB_EMCY + node.node_id, struct.pack("<HBBI", EMCY_SENSOR, 0x01, status, 0))

    def _reported_nm(self, node: _Node, x_um: np.ndarray) -> np.ndarray:
        """Scale, optional one-pole filter, quantise to resolution_nm, clip to int32."""
        v = node.values
        x_nm = x_um * 1000.0 * v["scale_ppm"] / 1e6
        if v["filter_hz"] > 0:
            alpha = 1.0 - np.exp(-2 * np.pi * v["filter_hz"] / self.sample_rate_hz)
            out = np.empty_like(x_nm)
            y = x_nm[0] if node.filtered is None else node.filtered
            for k, xk in enumerate(x_nm):
                y += alpha * (xk - y)
                out[k] = y
            node.filtered = y
            x_nm = out
        res = v["resolution_nm"]
        return np.clip(np.round(x_nm / res) * res, -(2**31), 2**31 - 1)

    def _sdo(self, node: _Node, data: bytes) -> None:
        if len(data) != 8:
            return
        cs, index, sub = data[0], int.from_bytes(data[1:3], "little"), data[3]
        reply_cob = COB_SDO_TX + node.node_id
        entry = OD.get((index, sub))
        if entry is None:
            self._send(reply_cob, sdo_abort(index, sub, 0x06020000))
            return
        name, size, writable, lo, hi = entry
        if cs == 0x40:
            value = node.values[name]
            self._send(
                reply_cob,
                bytes([sdo_size_cs(size, read=True)]) + data[1:4] + int(value).to_bytes(4, "little", signed=False),
            )
        elif cs in (0x2F, 0x2B, 0x23):
            if not writable:
                self._send(reply_cob, sdo_abort(index, sub, 0x06010002))
            elif cs != sdo_size_cs(size, read=False):
                self._send(reply_cob, sdo_abort(index, sub, 0x06070010))
            else:
                value = int.from_bytes(data[4 : 4 + size], "little")
                if not lo <= value <= hi:
                    self._send(reply_cob, sdo_abort(index, sub, 0x06090030))
                else:
                    node.values[name] = value
                    self._send(reply_cob, bytes([0x60]) + data[1:4] + bytes(4))
        else:
            self._send(reply_cob, sdo_abort(index, sub, 0x05040001))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.bus.shutdown()
