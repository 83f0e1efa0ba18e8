"""Datasets of emulated benches recorded straight into a store, as a sweep job would record them
(service.usecases.acquire.run_sweep: the same plan checks, arrays, block table and bench snapshot),
without a service: the batch benchmark's and the lab tests' data.

The dataset carries its bench id: in the row's ``bench_id`` where the store has that column, and
as the tag ``bench:<id>`` (read back by ``bench_id_of``) where it has not.
"""
from __future__ import annotations

from drivers.emulated import open_bench
from service.store import Store
from service.usecases.plans import SinePlan, plan_for_bench, trim_blocks
from service.usecases.recorder import bench_snapshot, record_arrays

#: the tag that names a dataset's or model's bench where the store has no bench_id column
BENCH_TAG = "bench:"


def bench_id_of(row: dict) -> str | None:
    """The bench a dataset or model row comes from: its ``bench_id`` column, else its
    ``bench:<id>`` tag; None when neither says."""
    if row.get("bench_id"):
        return row["bench_id"]
    return next((t[len(BENCH_TAG):] for t in row.get("tags") or [] if t.startswith(BENCH_TAG)), None)


def bench_labels(bench_id: str | None) -> dict:
    """The fields that mark a new row as ``bench_id``'s (``bench_id`` and its tag)."""
    return {} if bench_id is None else {"bench_id": bench_id, "tags": [BENCH_TAG + bench_id]}


def record_emulated_sweep(store: Store, bench: str, seed: int, bench_id: str | None = None,
                          frequencies_hz=(10.0, 50.0), cycles: int = 4, axes=("y", "z"),
                          name: str | None = None) -> dict:
    """Run a sine sweep (0–120 V, the axes one after the other) on the emulated bench ``bench``
    (fixtures/benches/<bench>.toml, noise ``seed``) and store it as one dataset of ``bench_id``;
    the stored row."""
    device = open_bench(bench, seed)
    plan = SinePlan(axes=tuple(axes), frequencies_hz=tuple(float(f) for f in frequencies_hz), cycles=int(cycles),
                    together=False)
    planned = plan_for_bench(plan, device)
    record = device.run(planned.u_v, planned.sample_rate_hz)
    freqs = ",".join(f"{f:g}" for f in plan.frequencies_hz)
    meta = {"name": name or f"{bench} seed {seed}: sine {'+'.join(axes)} {freqs} Hz", "source": "sweep",
            "axes": sorted(record.x_um), "sample_rate_hz": record.sample_rate_hz,
            "blocks": trim_blocks(planned.blocks, record.samples, record.sample_rate_hz),
            "plan": {**plan.to_dict(), "samples": planned.samples, "duration_s": planned.duration_s},
            "config": bench_snapshot(device), **bench_labels(bench_id)}
    return store.add_dataset(record_arrays(record), meta)
