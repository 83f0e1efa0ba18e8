"""Sweeps: a characterisation plan checked against the bench, then run and recorded as one dataset.

The run is recorded by service.usecases.recorder: a cancelled or interrupted sweep keeps the
samples taken so far as a dataset marked ``partial`` (with the reason), a killed process loses at
most the last second of them, and the bench leaves its output at 0 V either way.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from drivers.bench import Bench
from drivers.limits import highest_sine_hz
from service.runtime.jobs import JobContext, JobInterrupted, JobManager
from service.science.data.plans import PlannedSweep, plan_for_bench, plan_from_dict, trim_blocks
from service.science.discovery.records import record_for_axis
from service.science.errors import FieldError
from service.store import TERMINAL_STATES, Store
from service.usecases.recorder import Recorder, bench_snapshot, record_arrays


def plan_sweep(bench: Bench, values: dict) -> tuple[PlannedSweep, dict]:
    """The sweep a request asks for (``SweepRequest`` fields but ``name``), sampled for this bench,
    and its plan as stored (with ``samples`` and ``duration_s``). FieldError (422) names the field
    if the plan leaves the bench's voltage, current or slew limits."""
    plan = plan_from_dict(values)
    planned = plan_for_bench(plan, bench)
    return planned, {**plan.to_dict(), "samples": planned.samples, "duration_s": planned.duration_s}


def runnable_sweep(bench: Bench, values: dict) -> tuple[dict, list[str]]:
    """``values`` (a /api/sweeps body) as the bench can run it, and the cuts made, in words: as given
    when ``plan_sweep`` accepts it; else its voltages clipped to each axis's range and every sine
    frequency above what the bench allows at that amplitude (current, slew, RESONANCE_FRACTION × the
    first resonance) brought down to the largest whole hertz it allows. FieldError naming the field
    if even that is refused. Never touches the hardware."""
    try:
        plan_sweep(bench, values)
        return values, []
    except FieldError:
        pass
    out, cuts = dict(values), []
    axes = list(values.get("axes") or ["y"])
    limits = [bench.limits[a] for a in axes if a in bench.limits]
    if limits:
        lo, hi = max(lim.v_min_v for lim in limits), min(lim.v_max_v for lim in limits)
        for key in ("v_min", "v_max"):
            if key in out and not lo <= out[key] <= hi:
                out[key] = min(max(out[key], lo), hi)
                cuts.append(f"{key} {values[key]:g} → {out[key]:g} V (the actuator's {lo:g}–{hi:g} V)")
        if out.get("levels_v"):
            plan = plan_from_dict(out)  # its voltage range, the defaults filled in
            out["levels_v"] = [min(max(v, plan.v_min), plan.v_max) for v in out["levels_v"]]
            if out["levels_v"] != list(values["levels_v"]):
                cuts.append(f"levels_v → {', '.join(f'{v:g}' for v in out['levels_v'])} V")
    if out.get("frequencies_hz") and limits:
        vpp = float(out.get("v_max", 120.0)) - float(out.get("v_min", 0.0))
        cap = min(highest_sine_hz(lim, vpp) for lim in limits)
        kept = sorted({f if f <= cap else float(math.floor(cap)) for f in out["frequencies_hz"]})
        if kept != sorted(out["frequencies_hz"]):
            cuts.append(
                f"frequencies_hz {', '.join(f'{f:g}' for f in out['frequencies_hz'])} → "
                f"{', '.join(f'{f:g}' for f in kept)} Hz (the bench allows at most {cap:.1f} Hz at {vpp:g} Vpp)"
            )
            out["frequencies_hz"] = kept
    plan_sweep(bench, out)  # FieldError naming the field if it is refused even so
    return out, cuts


def widest_sweep(bench: Bench, values: dict) -> dict | None:
    """A sine sweep ``values`` over its axes' whole common voltage range (a sine's fastest rate, π f
    Vpp, grows with its swing), or None where it spans that range already or is not a sine."""
    limits = [bench.limits[a] for a in values.get("axes") or ["y"] if a in bench.limits]
    if values.get("waveform", "sine") != "sine" or not limits:
        return None
    lo, hi = max(lim.v_min_v for lim in limits), min(lim.v_max_v for lim in limits)
    plan = plan_from_dict(values)
    return None if (plan.v_min, plan.v_max) == (lo, hi) else {**values, "v_min": lo, "v_max": hi}


def planned_records(bench: Bench, values: dict, axis: str) -> list:
    """The records sweep ``values`` would make on ``axis`` as this bench plans it: its drive, its
    block table and the amplifier's rated rate, the displacement not yet known (zeros), for a rule
    that reads the drive (an effect's ``untestable``). [] where the sweep does not drive ``axis``.
    Never touches the hardware."""
    planned, _ = plan_sweep(bench, values)
    if axis not in planned.u_v:
        return []
    arrays = {f"u_{a}_v": u for a, u in planned.u_v.items()}
    arrays.update({f"x_{a}_um": np.zeros_like(u) for a, u in planned.u_v.items()})
    blocks = trim_blocks(planned.blocks, planned.samples, planned.sample_rate_hz)
    rate = bench.limits[axis].max_rate_v_per_s
    return [record_for_axis("planned", arrays, planned.sample_rate_hz, blocks, axis, rate)]


@dataclass(frozen=True)
class BenchExperiments:
    """What a diagnosis or a discover job asks of the bench about a proposed experiment, without
    running it: ``cut`` (``runnable_sweep``), ``widest`` (``widest_sweep``) and ``records``
    (``planned_records``: what the sweep's drive would be, for the effect's own rule)."""

    bench: Bench

    def cut(self, values: dict) -> tuple[dict, list[str]]:
        return runnable_sweep(self.bench, values)

    def widest(self, values: dict) -> dict | None:
        return widest_sweep(self.bench, values)

    def records(self, values: dict, axis: str) -> list:
        return planned_records(self.bench, values, axis)


def queue_sweep(
    jobs: JobManager, bench: Bench, store: Store, values: dict, name: str | None = None
) -> tuple[dict, PlannedSweep]:
    """Plan a sweep (``plan_sweep``: FieldError naming the field if it leaves the bench's limits) and
    queue it as a bench job; ``(job, planned)``. POST /api/sweeps and the discover job's experiments.
    ``values["experiment_of"]`` (the diagnosis it is the experiment of), when given, is kept in the plan."""
    planned, plan = plan_sweep(bench, values)
    if values.get("experiment_of"):
        plan["experiment_of"] = values["experiment_of"]
    job = jobs.submit("sweep", plan, lambda ctx: run_sweep(ctx, bench, store, planned, plan, name), needs_bench=True)
    return job, planned


#: how often a job waiting for a sweep it queued looks at it (s)
SWEEP_POLL_S = 0.2


def sweep_and_wait(
    ctx: JobContext, jobs: JobManager, bench: Bench, store: Store, values: dict, name: str | None = None
) -> dict:
    """From inside another job: queue the sweep ``values`` (a /api/sweeps body) and wait until it ends;
    returns the sweep's job. When ``ctx`` is cancelled the sweep is cancelled too (its partial data is
    kept as a dataset) and JobInterrupted is raised."""
    job, _ = queue_sweep(jobs, bench, store, values, name)
    while True:
        row = jobs.get(job["id"])
        if row["state"] in TERMINAL_STATES:
            return row
        if ctx.cancelled:
            jobs.cancel(job["id"], f"its job {ctx.job_id} was cancelled")
            raise JobInterrupted(f"cancelled while sweep {job['id']} ran", cancelled=True)
        time.sleep(SWEEP_POLL_S)


def run_sweep(
    ctx: JobContext, bench: Bench, store: Store, planned: PlannedSweep, plan: dict, name: str | None = None
) -> dict:
    """Job body: stream ``planned`` through the bench, store the record, return
    ``{"dataset_id", "samples", "partial"}``. On a stop (cancel, fault) the partial record is
    stored and JobInterrupted carries that result."""
    duration = planned.duration_s
    meta = {
        "name": name or _default_name(plan),
        "source": "sweep",
        "axes": sorted(bench.axes),
        "sample_rate_hz": planned.sample_rate_hz,
        "blocks": planned.blocks,
        "plan": plan,
        "config": bench_snapshot(bench),
    }

    def progress(fraction: float) -> None:
        ctx.progress(0.98 * fraction, f"sweeping: {fraction * duration:.1f} of {duration:.1f} s")

    ctx.progress(0.0, f"sweeping: 0 of {duration:.1f} s")
    with Recorder(store, meta, ctx) as recorder:
        record, stop = recorder.run(bench, planned.u_v, planned.sample_rate_hz, progress)
        if record.samples == 0:
            raise recorder.nothing_kept(f"{stop.reason}; no samples were taken", stop.cancelled)
        # a stopped sweep's progress is the share it recorded, as its partial dataset holds it
        ctx.progress(0.99 if stop is None else record.samples / planned.samples, "storing")
        row = recorder.keep(
            record_arrays(record),
            stop,
            axes=sorted(record.x_um),
            sample_rate_hz=record.sample_rate_hz,
            blocks=trim_blocks(planned.blocks, record.samples, record.sample_rate_hz),
        )
    return recorder.end(row, {"dataset_id": row["id"], "samples": row["samples"], "partial": row["partial"]}, stop)


def _default_name(plan: dict) -> str:
    freqs = plan.get("frequencies_hz")
    detail = ",".join(f"{f:g}" for f in freqs) + " Hz" if freqs else plan.get("waveform", "")
    return f"{plan.get('waveform', 'sweep')} {'+'.join(plan.get('axes', []))} {detail}".strip()
