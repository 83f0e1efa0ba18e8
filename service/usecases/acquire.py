"""Running a planned sweep on the bench and storing what it measured as one dataset.

A cancelled or interrupted run keeps the samples taken so far: they are stored as a dataset
marked ``partial`` (with the reason), and the bench leaves its output at 0 V either way. While the
run goes on, its samples are also written in ~1 s fsync'ed chunks (service.store.chunks), so that
a killed process loses at most the last second: service.runtime.recovery rebuilds a partial dataset from
them at the next start.
"""
from __future__ import annotations

import numpy as np

from drivers.bench import Bench, BenchRecord, RunInterrupted
from service.science.data.datasets import units_for
from service.runtime.jobs import JobContext, JobInterrupted
from service.store import Store, utc_now
from service.store.chunks import ChunkWriter
from service.usecases.plans import PlannedSweep, trim_blocks


def bench_snapshot(bench: Bench) -> dict:
    """The full configuration of the bench: backend, every driver/emulator parameter, limits."""
    return {"backend": bench.parts.backend, "parameters": bench.parts.config,
            "limits": {axis: lim.as_dict() for axis, lim in bench.limits.items()},
            "amplifier_gain_v_per_v": {a: amp.gain_v_per_v for a, amp in bench.parts.amplifiers.items()},
            "sensor_scale_um_per_v": {a: s.scale_um_per_v for a, s in bench.parts.sensors.items()}}


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


def run_sweep(ctx: JobContext, bench: Bench, store: Store, planned: PlannedSweep, plan: dict,
              name: str | None = None) -> dict:
    """Stream ``planned`` through the bench, store the record, return ``{"dataset_id", …}``.

    On a stop (cancel, fault) the partial record is stored and JobInterrupted carries its id.
    """
    duration = planned.duration_s
    started_at = utc_now()
    meta = {"name": name or _default_name(plan), "source": "sweep", "axes": sorted(bench.axes),
            "sample_rate_hz": planned.sample_rate_hz, "blocks": planned.blocks, "plan": plan,
            "config": bench_snapshot(bench), "job_id": ctx.job_id, "started_at": started_at}
    chunks = ChunkWriter(store.data_dir, ctx.job_id, meta)

    def on_block(record: BenchRecord, fraction: float) -> None:
        chunks.append(record_arrays(record, start=chunks.rows_seen))  # the new rows only
        ctx.progress(0.98 * fraction, f"sweeping: {fraction * duration:.1f} of {duration:.1f} s")

    ctx.progress(0.0, f"sweeping: 0 of {duration:.1f} s")
    try:
        try:
            record = bench.run(planned.u_v, planned.sample_rate_hz, on_block=on_block,
                               should_stop=lambda: ctx.cancelled)
            reason, stopped = None, False
        except RunInterrupted as exc:
            record, reason, stopped = exc.record, exc.reason, exc.stopped
        if record.samples == 0:
            raise JobInterrupted(f"{reason}; no samples were taken", None, cancelled=stopped)
        arrays = record_arrays(record)
        ctx.progress(0.99, "storing")
        row = store.add_dataset(arrays, {
            **meta, "axes": sorted(record.x_um), "sample_rate_hz": record.sample_rate_hz,
            "blocks": trim_blocks(planned.blocks, record.samples, record.sample_rate_hz),
            "units": units_for(arrays), "partial": reason is not None, "partial_reason": reason,
            "finished_at": utc_now()})
    finally:  # stored (or nothing to keep): the chunks are only for a process that dies mid-run
        chunks.discard()
    result = {"dataset_id": row["id"], "samples": row["samples"], "partial": row["partial"],
              **({"warnings": chunks.warnings()} if chunks.warnings() else {})}
    if reason is not None:
        raise JobInterrupted(f"{reason}: {row['samples']} samples kept as partial dataset {row['id']}", result,
                             cancelled=stopped)
    return result


def _default_name(plan: dict) -> str:
    freqs = plan.get("frequencies_hz")
    detail = ",".join(f"{f:g}" for f in freqs) + " Hz" if freqs else plan.get("waveform", "")
    return f"{plan.get('waveform', 'sweep')} {'+'.join(plan.get('axes', []))} {detail}".strip()
