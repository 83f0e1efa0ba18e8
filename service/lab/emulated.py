"""Sweeps of emulated benches without a service: as Records (``sweep_records``: the reports', the
benchmarks' and the tests' data), or recorded straight into a store as a sweep job would record them
(``record_emulated_sweep``; service.usecases.acquire.run_sweep: the same plan checks, arrays, block
table and bench snapshot): the batch benchmark's and the lab tests' data.
"""

from __future__ import annotations

from drivers.factory import open_bench
from service.science.data.plans import SinePlan, plan_for_bench, plan_from_dict, trim_blocks
from service.science.data.record import Record
from service.science.discovery.records import run_records
from service.store import Store
from service.usecases.recorder import bench_snapshot, record_arrays


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
    """Run a sine characterisation (or ``plan``, a /api/sweeps-style body) on the emulated bench
    ``bench`` (fixtures/benches/<bench>.toml, noise ``seed``; its configuration changed by
    ``overrides``, dotted keys) and return ``{axis: Record}`` (service.science.discovery.records)."""
    if plan is not None:
        sweep = plan_from_dict({**plan, "axes": tuple(plan.get("axes", axes))})
    else:
        sweep = SinePlan(axes=tuple(axes), frequencies_hz=tuple(frequencies_hz), cycles=cycles, together=together)
    return run_records(open_bench(bench, seed, overrides), sweep, bench + ":")


def record_emulated_sweep(
    store: Store,
    bench: str,
    seed: int,
    bench_id: str | None = None,
    frequencies_hz=(10.0, 50.0),
    cycles: int = 4,
    axes=("y", "z"),
    name: str | None = None,
) -> dict:
    """Run a sine sweep (0–120 V, the axes one after the other) on the emulated bench ``bench``
    (fixtures/benches/<bench>.toml, noise ``seed``) and store it as one dataset of ``bench_id``
    (the store carries that bench id while it adds the row, as a bench's service's store does; not
    for a store other threads write to meanwhile); the stored row."""
    device = open_bench(bench, seed)
    plan = SinePlan(
        axes=tuple(axes), frequencies_hz=tuple(float(f) for f in frequencies_hz), cycles=int(cycles), together=False
    )
    planned = plan_for_bench(plan, device)
    record = device.run(planned.u_v, planned.sample_rate_hz)
    freqs = ",".join(f"{f:g}" for f in plan.frequencies_hz)
    meta = {
        "name": name or f"{bench} seed {seed}: sine {'+'.join(axes)} {freqs} Hz",
        "source": "sweep",
        "axes": sorted(record.x_um),
        "sample_rate_hz": record.sample_rate_hz,
        "blocks": trim_blocks(planned.blocks, record.samples, record.sample_rate_hz),
        "plan": {**plan.to_dict(), "samples": planned.samples, "duration_s": planned.duration_s},
        "config": bench_snapshot(device),
    }
    own = store.bench_id
    store.bench_id = bench_id
    try:
        return store.add_dataset(record_arrays(record), meta)
    finally:
        store.bench_id = own
