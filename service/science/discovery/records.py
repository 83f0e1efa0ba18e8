"""Records for discovery: one axis of one measured dataset with its blocks, its train/held-out
split (whole held-out cycles, service.science.fitting.validation) and the other axis's drive (for coupling).
Pure numpy: no store, no HTTP."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from service.science.data.segmentation import blocks_without_table
from service.science.data.signals import dominant_period_samples, savgol_derivatives
from service.science.fitting.validation import split_blocks, training_mask

#: keep at least this many samples per cycle in the rows a fit uses (long slow blocks are decimated)
FIT_SAMPLES_PER_CYCLE = 400
#: rows a fit keeps of one non-periodic block (a step-hold: slow, so evenly decimated)
MAX_STEP_ROWS = 4000


def drive_derivatives(u_v: np.ndarray, sample_rate_hz: float, blocks: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """u̇ (V/s) and ü (V/s²) of a recorded drive: Savitzky–Golay within each periodic block over a
    window set by that block's own period, central differences elsewhere."""
    du = np.gradient(u_v, 1.0 / sample_rate_hz)
    ddu = np.gradient(du, 1.0 / sample_rate_hz)
    for block in blocks:
        start, stop = int(block["start"]), min(int(block["stop"]), len(u_v))
        f_hz = block.get("frequency_hz")
        if stop - start < 8:
            continue
        period = sample_rate_hz / f_hz if f_hz else None
        du[start:stop], ddu[start:stop] = savgol_derivatives(u_v[start:stop], sample_rate_hz, period)
    return du, ddu


@dataclass
class Record:
    """``u_v`` drive (V), ``x_um`` displacement (µm), ``fs_hz``, block table, optional other-axis drive
    (V) and measured other-axis displacement (µm)."""

    label: str
    u_v: np.ndarray
    x_um: np.ndarray
    fs_hz: float
    blocks: list = field(default_factory=list)
    axis: str | None = None
    u_other_v: np.ndarray | None = None
    x_other_um: np.ndarray | None = None

    def __post_init__(self):
        self.u_v = np.asarray(self.u_v, dtype=float)
        self.x_um = np.asarray(self.x_um, dtype=float)
        if not self.blocks:   # no block table: as an import would cut it
            axis = self.axis or "y"
            drives = {axis: self.u_v}
            if self.u_other_v is not None:
                drives[{"y": "z", "z": "y"}.get(axis, "other")] = self.u_other_v
            self.blocks = blocks_without_table(drives, self.fs_hz)
        # every block, also those that drive only the other axis: they show coupling
        self.splits = split_blocks(self.blocks, self.u_v.size, self.fs_hz)
        self.train = training_mask(self.splits, self.u_v.size)
        self.du, self.ddu = drive_derivatives(self.u_v, self.fs_hz, self.blocks)

    @property
    def n(self) -> int:
        return self.u_v.size

    def period_samples(self, split) -> float | None:
        """Samples per cycle of a block: from its frequency; for an imported record without a
        block table, the drive's dominant period; None for steps and other non-periodic blocks."""
        f = split.block.get("frequency_hz")
        if f:
            return self.fs_hz / float(f)
        if split.block.get("kind") not in (None, "imported"):
            return None
        a, b = split.train[0], split.held_out[1]
        return float(dominant_period_samples(self.u_v[a:b]))

    def min_period_s(self) -> float:
        periods = [p for p in (self.period_samples(s) for s in self.splits) if p]
        return (min(periods) if periods else float(dominant_period_samples(self.u_v))) / self.fs_hz

    def fit_rows(self, exclude_frequency_hz: float | None = None) -> np.ndarray:
        """Indices of the training rows a fit uses: every block's training cycles, decimated to
        about FIT_SAMPLES_PER_CYCLE samples per cycle (blocks at ``exclude_frequency_hz`` left out)."""
        rows = []
        for s in self.splits:
            if exclude_frequency_hz is not None and s.block.get("frequency_hz") == exclude_frequency_hz:
                continue
            period = self.period_samples(s)
            span = s.train[1] - s.train[0]
            stride = max(1, int(period // FIT_SAMPLES_PER_CYCLE)) if period else max(1, span // MAX_STEP_ROWS)
            rows.append(np.arange(s.train[0], s.train[1], stride))
        return np.concatenate(rows) if rows else np.zeros(0, dtype=int)


def record_for_axis(label: str, arrays: dict, fs_hz: float, blocks: list, axis: str) -> Record:
    """The Record of ``axis`` from dataset-style arrays (``u_<axis>_v``, ``x_<axis>_um``), with the
    other axis's drive and measured displacement when the arrays have them."""
    other = [a for a in ("y", "z") if a != axis and f"u_{a}_v" in arrays]
    u_other = arrays[f"u_{other[0]}_v"] if other else None
    x_other = arrays.get(f"x_{other[0]}_um") if other else None
    return Record(label, arrays[f"u_{axis}_v"], arrays[f"x_{axis}_um"], fs_hz, blocks, axis, u_other, x_other)


def records_from_arrays(arrays: dict, fs_hz: float, blocks: list, axes, label: str = "") -> list[Record]:
    """One Record per axis, labelled ``<label><axis>``."""
    return [record_for_axis(f"{label}{axis}", arrays, fs_hz, blocks, axis) for axis in axes]


def sweep_records(bench: str, seed: int = 0, frequencies_hz=(1.0, 10.0, 50.0, 100.0), cycles: int = 5,
                  axes=("y", "z"), together: bool = False, plan: dict | None = None,
                  overrides: dict | None = None) -> dict[str, Record]:
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
    return out
