"""The emulator on the wire: the same World behind real transports.

- ``Mdt693bResponder``: the amplifier's MDT693B serial protocol on a pseudo-terminal;
- ``EmulatedGaugeNodes``: the gauges as CANopen nodes on a python-can bus;
- ``WireDaq``: the in-process DAQ (the fast analog path) that sums the serial DC set-points into
  the modulation input and hands each block's gauge readings to the CAN nodes. When the nodes
  stream positions, its AI gauge columns are NaN: positions exist on the host only as they
  arrive over CAN.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from drivers.emulated.devices import EmulatedDaq
from drivers.emulated.wire.canopen_gauge import EmulatedGaugeNodes
from drivers.emulated.wire.mdt693b import Mdt693bResponder

__all__ = ["Mdt693bResponder", "EmulatedGaugeNodes", "WireDaq"]
CHANNEL = {"y": 0, "z": 1}  # each axis's AO channel and gauge AI channel


class WireDaq:
    """An EmulatedDaq whose amplifiers and gauges live behind the wire emulators (either may be None)."""

    def __init__(self, inner: EmulatedDaq, responder: Mdt693bResponder | None, nodes: EmulatedGaugeNodes | None):
        self.inner, self.responder, self.nodes = inner, responder, nodes
        self.world = inner.world
        self.capabilities = inner.capabilities

    @property
    def sample_rate_hz(self) -> float:
        return self.inner.sample_rate_hz

    def configure(self, sample_rate_hz: float) -> float:
        return self.inner.configure(sample_rate_hz)

    def _with_setpoints(self, ao: np.ndarray) -> np.ndarray:
        if self.responder is None:
            return ao
        ao = np.array(ao, dtype=float, copy=True)
        for ch, axis in self.responder.channel_axis.items():
            sp = self.responder.setpoint_v[ch]
            if sp:
                gain = self.world.config["axes"][axis]["amplifier"]["gain_v_per_v"]
                ao[..., CHANNEL[axis]] += sp / gain
        return ao

    def _to_wire(self, ai: np.ndarray) -> np.ndarray:
        if self.nodes is None:
            return ai
        block = np.atleast_2d(ai)
        scale = {ax: self.world.config["axes"][ax]["gauge"]["scale_um_per_v"] for ax in CHANNEL}
        self.nodes.capture({ax: block[:, ch] * scale[ax] for ax, ch in CHANNEL.items() if ax in self.nodes.nodes})
        if not self.nodes.stream:
            return ai
        ai = np.array(ai, copy=True)
        for ch in CHANNEL.values():
            ai[..., ch] = np.nan
        return ai

    def write_read(self, ao_daq_v: np.ndarray) -> np.ndarray:
        return self._to_wire(self.inner.write_read(self._with_setpoints(ao_daq_v)))

    def step(self, ao_daq_v: Sequence[float]) -> np.ndarray:
        return self._to_wire(self.inner.step(list(self._with_setpoints(np.asarray(ao_daq_v, dtype=float)))))

    def write_idle(self) -> None:
        self.inner.write_idle()

    def arm_watchdog(self, timeout_s: float) -> dict | None:
        return self.inner.arm_watchdog(timeout_s)

    def pet_watchdog(self) -> str | None:
        return self.inner.pet_watchdog()

    def clear_watchdog(self) -> None:
        self.inner.clear_watchdog()

    def begin_session(self) -> None:
        self.inner.begin_session()

    def close(self) -> None:
        self.inner.close()
