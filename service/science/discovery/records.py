"""Discovery's records: one axis of one measured dataset (service.science.data.record.Record,
held out by whole cycles: service.science.data.holdout) with the other axis's drive and
displacement (for coupling), from dataset-style arrays or a sweep run on a bench (an emulated bench
by name: service.lab.emulated.sweep_records). Pure numpy: no store, no HTTP."""

from __future__ import annotations

import numpy as np

from drivers.bench import Bench
from service.science.data.plans import plan_for_bench, trim_blocks
from service.science.data.record import Record


def record_for_axis(
    label: str, arrays: dict, sample_rate_hz: float, blocks: list, axis: str, rated_rate_v_per_s: float | None = None
) -> Record:
    """The held-out Record of ``axis`` from dataset-style arrays (``u_<axis>_v``, ``x_<axis>_um``),
    with the other axis's drive and measured displacement when the arrays have them, and the
    amplifier's rated rate (V/s) where the bench that recorded it is known; ValueError (naming the
    array and the label) if it cannot be modelled."""
    other = [a for a in ("y", "z") if a != axis and f"u_{a}_v" in arrays]
    u_other = arrays[f"u_{other[0]}_v"] if other else None
    x_other = arrays.get(f"x_{other[0]}_um") if other else None
    return Record(
        arrays[f"u_{axis}_v"],
        arrays[f"x_{axis}_um"],
        sample_rate_hz,
        label=label,
        blocks=blocks,
        axis=axis,
        u_other_v=u_other,
        x_other_um=x_other,
        hold_out=True,
        temp_c=arrays.get("temp_c"),
        rated_rate_v_per_s=rated_rate_v_per_s,
    )


def records_from_arrays(
    arrays: dict, sample_rate_hz: float, blocks: list, axes, label: str = "", rated_rates_v_per_s: dict | None = None
) -> list[Record]:
    """One Record per axis, labelled ``<label><axis>`` (``rated_rates_v_per_s``: the amplifier's rated
    rate per axis, V/s, where the bench is known)."""
    rates = rated_rates_v_per_s or {}
    return [record_for_axis(f"{label}{axis}", arrays, sample_rate_hz, blocks, axis, rates.get(axis)) for axis in axes]


def run_records(bench: Bench, sweep, label: str = "") -> dict[str, Record]:
    """Run the sweep plan ``sweep`` (service.science.data.plans: SinePlan, …) on ``bench`` and return
    ``{axis: Record}`` of its axes, held out by whole cycles and labelled ``<label><axis>``."""
    planned = plan_for_bench(sweep, bench)
    rec = bench.run(planned.u_v, planned.sample_rate_hz)
    blocks = trim_blocks(planned.blocks, rec.samples, rec.sample_rate_hz)
    rates = {axis: bench.limits[axis].max_rate_v_per_s for axis in sweep.axes}
    return {r.axis: r for r in records_from_arrays(_arrays(rec), rec.sample_rate_hz, blocks, sweep.axes, label, rates)}


def _arrays(rec) -> dict:
    out = {}
    for axis in rec.x_um:
        out[f"u_{axis}_v"] = np.asarray(rec.u_cmd_v[axis], dtype=float)
        out[f"x_{axis}_um"] = np.asarray(rec.x_um[axis], dtype=float)
    temp = rec.extra.get("temp_c") if getattr(rec, "extra", None) else None
    if temp is not None and len(temp) == rec.samples:
        out["temp_c"] = np.asarray(temp, dtype=float)
    return out
