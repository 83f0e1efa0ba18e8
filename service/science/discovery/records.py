"""Discovery's records: one axis of one measured dataset (service.science.data.record.Record,
held out by whole cycles: service.science.fitting.validation) with the other axis's drive and
displacement (for coupling), from dataset-style arrays or an emulated sweep.
Pure numpy: no store, no HTTP."""

from __future__ import annotations

import numpy as np

from service.science.data.record import Record


def record_for_axis(label: str, arrays: dict, sample_rate_hz: float, blocks: list, axis: str) -> Record:
    """The held-out Record of ``axis`` from dataset-style arrays (``u_<axis>_v``, ``x_<axis>_um``),
    with the other axis's drive and measured displacement when the arrays have them; ValueError
    (naming the array and the label) if it cannot be modelled."""
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
    )


def records_from_arrays(arrays: dict, sample_rate_hz: float, blocks: list, axes, label: str = "") -> list[Record]:
    """One Record per axis, labelled ``<label><axis>``."""
    return [record_for_axis(f"{label}{axis}", arrays, sample_rate_hz, blocks, axis) for axis in axes]


def sweep_records(
    bench: str,
    seed: int = 0,
    frequencies_hz=(1.0, 10.0, 50.0, 100.0),
    cycles: int = 5,
    axes=("y", "z"),
    together: bool = False,
    plan: dict | None = None,
    overrides: dict | None = None,
) -> dict[str, Record]:
    """Run a sine characterisation (or ``plan``, a /api/sweeps-style body) on an emulated bench
    (its configuration changed by ``overrides``, dotted keys) and return ``{axis: Record}``."""
    from drivers.emulated import open_bench
    from service.usecases.plans import SinePlan, plan_for_bench, plan_from_dict, trim_blocks

    b = open_bench(bench, seed, overrides)
    if plan is not None:
        axes = tuple(plan.get("axes", axes))
        sweep = plan_from_dict({**plan, "axes": axes})
    else:
        sweep = SinePlan(axes=tuple(axes), frequencies_hz=tuple(frequencies_hz), cycles=cycles, together=together)
    planned = plan_for_bench(sweep, b)
    rec = b.run(planned.u_v, planned.sample_rate_hz)
    blocks = trim_blocks(planned.blocks, rec.samples, rec.sample_rate_hz)
    return {r.axis: r for r in records_from_arrays(_arrays(rec), rec.sample_rate_hz, blocks, axes, bench + ":")}


def _arrays(rec) -> dict:
    out = {}
    for axis in rec.x_um:
        out[f"u_{axis}_v"] = np.asarray(rec.u_cmd_v[axis], dtype=float)
        out[f"x_{axis}_um"] = np.asarray(rec.x_um[axis], dtype=float)
    temp = rec.extra.get("temp_c") if getattr(rec, "extra", None) else None
    if temp is not None and len(temp) == rec.samples:
        out["temp_c"] = np.asarray(temp, dtype=float)
    return out
