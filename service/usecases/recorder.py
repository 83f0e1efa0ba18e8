"""The recorder: how every acquisition becomes one stored dataset (sweeps, trajectories, imports).

Plans only describe what to run (service.science.data.plans, ``track_plan``); the bench runs them
(``Bench.run``, ``Bench.execute``: in this process or in the engine's, service/runtime/engine.py);
the recorder keeps what they measured:

- while a job's run goes on, its new rows are written in ~1 s fsync'ed chunks
  (service.store.chunks.ChunkWriter), so a killed process loses at most the last second and
  service.runtime.recovery rebuilds a partial dataset from them at the next start;
- at the end the whole record is stored as one dataset; a run that stopped early (cancel,
  emergency stop, fault) is stored ``partial`` with its reason (``Stop``);
- the job then ends with JobInterrupted carrying the partial result, whose message names the
  dataset and how many samples it kept.

The chunks are removed once the dataset is stored, or when nothing is to be kept.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from drivers.bench import Bench
from drivers.record import BenchRecord, RunInterrupted
from service.runtime.jobs import JobContext, JobInterrupted
from service.science.data.datasets import units_for
from service.store import DatasetRow, Store, placement, utc_now
from service.store.chunks import ChunkWriter, read_chunks


@dataclass(frozen=True)
class Stop:
    """Why a run ended before its plan did. ``reason`` is stored as the dataset's ``partial_reason``;
    ``message`` heads the job's message (default: the reason); ``cancelled`` is True when it was
    stopped on request (cancel, emergency stop, signal), False for a fault or a trip."""

    reason: str | None
    cancelled: bool = False
    message: str | None = None


def bench_snapshot(bench: Bench) -> dict:
    """The full configuration of the bench: backend, every driver/emulator parameter, limits."""
    return {
        "backend": bench.parts.backend,
        "parameters": bench.parts.config,
        "limits": {axis: lim.as_dict() for axis, lim in bench.limits.items()},
        "amplifier_gain_v_per_v": {a: amp.gain_v_per_v for a, amp in bench.parts.amplifiers.items()},
        "sensor_scale_um_per_v": {a: s.scale_um_per_v for a, s in bench.parts.sensors.items()},
    }


def record_arrays(record: BenchRecord, start: int = 0) -> dict[str, np.ndarray]:
    """Rows ``start:`` of a bench record as dataset arrays: t_s, then u_<axis>_v and x_<axis>_um, then temp_c."""
    arrays = {"t_s": np.arange(start, record.samples) / record.sample_rate_hz}
    for axis in sorted(record.x_um):
        arrays[f"u_{axis}_v"] = np.asarray(record.u_cmd_v[axis][start:], dtype=float)
        arrays[f"x_{axis}_um"] = np.asarray(record.x_um[axis][start:], dtype=float)
    for name, values in record.extra.items():
        if name == "temp_c" and len(values) == record.samples:
            arrays["temp_c"] = np.asarray(values[start:], dtype=float)
    return arrays


class Recorder:
    """Records one acquisition as one dataset; use it as a context manager (the chunks go at exit).

    ``meta`` is the dataset metadata known at the start (name, source, axes, sample_rate_hz,
    blocks, plan, config; see ``Store.add_dataset``). With a job's ``ctx`` the rows it is given are
    chunked on disk while the run goes on and the dataset carries the job id and the acquisition's
    start and end times; without one (an import, whose rows arrive at once) nothing is chunked.
    """

    def __init__(self, store: Store, meta: dict, ctx: JobContext | None = None):
        self.store, self.ctx = store, ctx
        self.meta = dict(meta)
        self._chunks, self._closed, self._pending = None, False, None
        if ctx is not None:
            self.meta.update(job_id=ctx.job_id, started_at=utc_now())
            self._chunks = ChunkWriter(store.data_dir, ctx.job_id, self.meta)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ while it runs
    def append(self, arrays: Mapping[str, np.ndarray]) -> None:
        """New rows of the running record (one 1-D array per column), chunked to disk."""
        self._chunks.append(arrays)

    @property
    def rows_seen(self) -> int:
        """Rows appended so far."""
        return self._chunks.rows_seen

    def should_stop(self) -> bool:
        """True once the job was cancelled (the bench then stops at its next block or period)."""
        return self.ctx is not None and self.ctx.cancelled

    def run(
        self,
        bench: Bench,
        u_v: Mapping[str, np.ndarray],
        sample_rate_hz: float,
        progress: Callable[[float], None] | None = None,
    ) -> tuple[BenchRecord, Stop | None]:
        """``bench.run`` a buffered waveform (volts at the actuator, hertz), each block's new rows
        appended and ``progress(fraction done)`` called; returns the record (so far, on a stop) and
        the Stop, None if it ran to the end."""

        def on_block(record: BenchRecord, fraction: float) -> None:
            self.append(record_arrays(record, start=self.rows_seen))  # the new rows only
            if progress is not None:
                progress(fraction)

        try:
            return bench.run(u_v, sample_rate_hz, on_block=on_block, should_stop=self.should_stop), None
        except RunInterrupted as exc:
            return exc.record, Stop(exc.reason, cancelled=exc.stopped)

    def execute(self, bench: Bench, plan: Callable, *args, on_event: Callable | None = None):
        """``bench.execute(plan, *args)`` (``plan`` a module-level function, ``args`` plain data),
        stopped when the job is cancelled; ``on_event(*payload)`` sees each event the plan emits
        and appends its new rows."""
        return bench.execute(plan, *args, on_event=on_event, should_stop=self.should_stop)

    # ------------------------------------------------------------------ at the end
    def keep(self, arrays: Mapping[str, np.ndarray], stop: Stop | None = None, **meta) -> DatasetRow:
        """Store ``arrays`` as the dataset (``meta`` overrides what was known at the start), partial
        with ``stop.reason`` when the run stopped early; the chunks are removed. Returns the row."""
        final = {
            **self.meta,
            **meta,
            "units": units_for(arrays),
            "partial": stop is not None,
            "partial_reason": None if stop is None else stop.reason,
        }
        if self.ctx is not None:
            final["finished_at"] = utc_now()
        try:  # a measurement is kept (in the outbox) if the shared array location is down; an import is not
            row = self.store.add_dataset(dict(arrays), final, keep_if_unreachable=self.ctx is not None)
        finally:
            self.close()
        if placement.pending(row["file"]):
            self._pending = (
                f"the arrays wait on this service's disk ({row['file']}) for the shared array store "
                f"{self.store.array_url}, which did not answer; they are uploaded when it does"
            )
        return row

    def keep_written(self, stop: Stop) -> DatasetRow | None:
        """The rows appended so far (the run ended without its record: the bench engine was lost)
        stored as a partial dataset with ``stop.reason``; None if none was appended."""
        if self._chunks is None or not self._chunks.rows_seen:
            return None
        self._chunks.flush()
        arrays, _problems = read_chunks(self._chunks.directory)
        return self.keep(arrays, stop) if arrays else None

    def end(self, row: DatasetRow, result: dict, stop: Stop | None) -> dict:
        """The job's result, with any warning about the chunks; on a ``stop``, JobInterrupted
        carrying it instead (the job ends cancelled or failed, its partial dataset named)."""
        if self.warnings():
            result["warnings"] = result.get("warnings", []) + self.warnings()
        if stop is None:
            return result
        raise JobInterrupted(
            f"{stop.message or stop.reason}: {row['samples']} samples kept as partial dataset {row['id']}",
            result,
            cancelled=stop.cancelled,
        )

    @staticmethod
    def nothing_kept(message: str, cancelled: bool) -> JobInterrupted:
        """The interruption of a run that stopped before it measured anything worth a dataset."""
        return JobInterrupted(message, None, cancelled=cancelled)

    def warnings(self) -> list[str]:
        """A chunk write that failed (crash safety was lost for this run), or arrays kept in the outbox
        (service.store.placement), in words."""
        return ([] if self._chunks is None else self._chunks.warnings()) + ([self._pending] if self._pending else [])

    def close(self) -> None:
        """Stop the chunk writer and remove the chunks (stored, or nothing to keep); once."""
        if self._chunks is not None and not self._closed:
            self._closed = True
            self._chunks.discard()
