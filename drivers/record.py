"""What a buffered run of the bench measured: ``BenchRecord`` (per-axis arrays, one value per sample),
``Acquired`` (the run's samples in preallocated arrays) and ``RunInterrupted`` (a run that stopped
early, with the data so far). Units: V for drives, µm for displacements, Hz, °C."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from drivers.interfaces import DriverError

if TYPE_CHECKING:
    from drivers.bench import Bench


class RunInterrupted(DriverError):
    """A run stopped early (cancel, device fault, sensor loss). ``record`` holds the data so far."""

    def __init__(self, reason: str, record: BenchRecord, stopped: bool = False):
        super().__init__(reason)
        self.reason = reason
        self.record = record
        self.stopped = stopped  # True: a stop request (cancel, emergency stop, signal); False: a fault


@dataclass
class BenchRecord:
    """What a buffered run measured. Arrays are per axis, one value per sample."""

    sample_rate_hz: float
    u_cmd_v: dict[str, np.ndarray]
    x_um: dict[str, np.ndarray]
    partial: bool = False
    reason: str | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def samples(self) -> int:
        return len(next(iter(self.x_um.values()))) if self.x_um else 0

    @property
    def t_s(self) -> np.ndarray:
        return np.arange(self.samples) / self.sample_rate_hz


class Acquired:
    """The samples of one buffered run in preallocated arrays, so adding a block and viewing the
    record so far cost O(block), never O(run) (a long sweep must not look like a stalled loop)."""

    def __init__(self, bench: Bench, n: int, rate_hz: float):
        self.bench, self.n, self.rate_hz, self.done = bench, n, rate_hz, 0
        self.u = {a: np.empty(n) for a in bench.axes}
        self.x = {a: np.empty(n) for a in bench.axes}
        reading = getattr(bench.parts.daq, "temperature_c", None)  # optional (drivers.interfaces.Daq)
        self._temperature_c = reading if callable(reading) else None
        self.temp: np.ndarray | None = None  # °C per sample, where the DAQ has a thermometer

    def add(self, u_blocks: Mapping[str, np.ndarray], ai: np.ndarray) -> None:
        parts, k = self.bench.parts, len(ai)
        for a in self.bench.axes:
            self.u[a][self.done : self.done + k] = u_blocks[a]
            self.x[a][self.done : self.done + k] = ai[:, parts.ai_channel[a]] * parts.sensors[a].scale_um_per_v
        temp = self._temperature_c() if self._temperature_c is not None else None
        if temp is not None:
            if self.temp is None:
                self.temp = np.full(self.n, np.nan)
            self.temp[self.done : self.done + k] = temp
        self.done += k

    def last_x_um(self, k: int) -> dict[str, np.ndarray]:
        """The last ``k`` displacement samples per axis (µm), as views."""
        return {a: v[self.done - k : self.done] for a, v in self.x.items()}

    def record(self) -> BenchRecord:
        extra = {} if self.temp is None else {"temp_c": self.temp[: self.done]}
        return BenchRecord(
            sample_rate_hz=self.rate_hz,
            u_cmd_v={a: v[: self.done] for a, v in self.u.items()},
            x_um={a: v[: self.done] for a, v in self.x.items()},
            extra=extra,
        )

    def interrupted(self, reason: str, stopped: bool = False) -> RunInterrupted:
        record = self.record()
        record.partial, record.reason = True, reason
        return RunInterrupted(reason, record, stopped=stopped)
