"""What the web process keeps of the bench engine's parts (service.runtime.engine): the static
figures, fault injection and live signals reached through the command pipe, and a run's record put
together from the rows the engine sends."""

from __future__ import annotations

from collections.abc import Mapping
from types import SimpleNamespace

import numpy as np

from drivers.record import BenchRecord, RunInterrupted


class _FaultView:
    """A fault the engine scheduled, as its ``Fault.as_dict()`` described it."""

    def __init__(self, described: dict):
        self._described = described

    def as_dict(self) -> dict:
        return dict(self._described)


class RemoteFaults:
    """Fault injection in the engine's emulator, as ``drivers.emulated.faults.FaultInjector`` offers it."""

    def __init__(self, command):
        self._command = command

    def add(self, kind: str, axis: str | None = None, after_s: float = 0.0) -> _FaultView:
        return _FaultView(self._command.call("faults_add", kind, axis, after_s))

    def list(self) -> list[dict]:
        return self._command.call("faults_list")["faults"]

    @property
    def transports(self) -> list[str]:
        return self._command.call("faults_list")["transports"]

    def clear(self) -> list[str]:
        return self._command.call("faults_clear")["notes"]


class RemoteLive:
    def __init__(self, command):
        self._command = command

    def since(self, cursor: int | None = None, max_points: int = 2000) -> dict:
        return self._command.call("live_since", cursor, max_points)


def parts_of(facts: dict, command) -> SimpleNamespace:
    """The static figures of the engine's parts, shaped as ``drivers.interfaces.BenchParts``."""
    axes = facts["axes"]
    return SimpleNamespace(
        backend=facts["backend"],
        config=facts["config"],
        resonance_hz=facts["resonance_hz"],
        ao_channel=facts["ao_channel"],
        ai_channel=facts["ai_channel"],
        amplifiers={
            a: SimpleNamespace(gain_v_per_v=facts["gain_v_per_v"][a], load_capacitance_f=facts["load_capacitance_f"][a])
            for a in axes
        },
        sensors={
            a: SimpleNamespace(scale_um_per_v=facts["scale_um_per_v"][a], range_um=facts["range_um"][a]) for a in axes
        },
        daq=SimpleNamespace(capabilities=facts["capabilities"], sample_rate_hz=facts["sample_rate_hz"]),
        world=SimpleNamespace(faults=RemoteFaults(command)) if facts["emulated"] else None,
    )


#: the arrays of a BenchRecord that hold one value per sample, by field name
_ROW_FIELDS = ("u_cmd_v", "x_um", "extra")


def _rows_from(record: BenchRecord, start: int) -> dict[tuple[str, str], np.ndarray]:
    """The record's rows ``start:`` as ``{(field, name): values}``: views, and the pipe pickles
    only the rows a view shows."""
    return {(field, name): values[start:] for field in _ROW_FIELDS for name, values in getattr(record, field).items()}


def run_buffered(bench, emit, u_v: Mapping[str, np.ndarray], sample_rate_hz: float, block_samples: int):
    """The plan behind ``EngineBench.run`` (runs in the engine): ``Bench.run``, sending each block's
    new rows as the event ``("block", start, rows, fraction)``. Returns what no event carried:
    ``(start, rows, sample_rate_hz, ending)``, ``ending`` None or ``(reason, stopped)`` of a
    RunInterrupted. Every row crosses the pipe once."""
    sent = 0

    def on_block(record: BenchRecord, fraction: float) -> None:
        nonlocal sent
        emit("block", sent, _rows_from(record, sent), fraction)
        sent = record.samples

    try:
        record, ending = bench.run(u_v, sample_rate_hz, block_samples=block_samples, on_block=on_block), None
    except RunInterrupted as exc:
        record, ending = exc.record, (exc.reason, exc.stopped)
    return sent, _rows_from(record, sent), record.sample_rate_hz, ending


class Assembled:
    """A run's record put together in the web process from the rows the engine sends, in
    preallocated arrays (``n`` samples each), so each block costs O(block), never O(run)."""

    def __init__(self, n: int):
        self.n, self.done = n, 0
        self.arrays: dict[tuple[str, str], np.ndarray] = {}

    def add(self, start: int, rows: dict[tuple[str, str], np.ndarray]) -> None:
        for key, values in rows.items():
            if key not in self.arrays:
                self.arrays[key] = np.full(self.n, np.nan)
            self.arrays[key][start : start + len(values)] = values
            self.done = start + len(values)

    def record(self, sample_rate_hz: float, reason: str | None = None) -> BenchRecord:
        """The record so far (views); ``reason`` marks it partial."""
        fields = {field: {} for field in _ROW_FIELDS}
        for (field, name), values in self.arrays.items():
            fields[field][name] = values[: self.done]
        return BenchRecord(sample_rate_hz, partial=reason is not None, reason=reason, **fields)
