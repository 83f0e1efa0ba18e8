"""The composite fit's transform search (service.science.discovery.composite): a delay and a
resonance both lag the output, so a search that fits one and then the other can stay in the basin
where the first took the whole lag. The fit must reach the better basin: no fit with the delay held
at another value (the resonance still searched) may beat it.

Seed 1's Z sweep on the default bench is such a case. The bench's truth (fixtures/benches/default.toml):
a 290.7 Hz mode at ζ 0.1 behind about 91 µs of lag (1 DAQ sample 50 µs, the 5 kHz amplifier 32 µs,
the 17.65 kHz gauge 9 µs). Delay searched first only: 235 µs, 300.2 Hz ζ 0.063, 0.088 µm RMS on the
training rows. With the resonance also searched first: 84 µs, 295.4 Hz ζ 0.114, 0.050 µm RMS. Over
REST the same two basins came out of one sweep's data by rounding alone (1 service run in 21 under
load), the likely cause of the CI failures at stops 28 and 29."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.emulated import open_bench
from service.science.discovery.composite import CompositeModel
from service.science.discovery.records import _arrays, records_from_arrays
from service.usecases.plans import SinePlan, plan_for_bench, trim_blocks

EFFECTS = ["hysteresis", "asymmetry", "creep", "delay", "dynamics"]

pytestmark = pytest.mark.slow


def _sweep_record(seed: int, axis: str):
    """One axis's default sweep (1/10/50/100 Hz, 0–120 V, 5 cycles) on the emulated default bench."""
    bench = open_bench("default", seed=seed)
    try:
        planned = plan_for_bench(SinePlan(axes=(axis,), frequencies_hz=(1.0, 10.0, 50.0, 100.0), cycles=5,
                                          v_min=0.0, v_max=120.0), bench)
        rec = bench.run(planned.u_v, planned.sample_rate_hz)
    finally:
        bench.close()
    blocks = trim_blocks(planned.blocks, rec.samples, rec.sample_rate_hz)
    (record,) = records_from_arrays(_arrays(rec), rec.sample_rate_hz, blocks, (axis,), f"{axis}:")
    return record


@pytest.mark.parametrize("seed,axis", [(1, "z"), (2, "y")])
def test_no_held_delay_beats_the_free_fit(seed, axis):
    record = _sweep_record(seed, axis)
    free = CompositeModel(EFFECTS, 10).fit([record])
    tau_max = min(0.2 * record.min_period_s(), 64.0 / record.sample_rate_hz)
    held = {}
    for delay_s in np.linspace(0.0, tau_max, 6):
        model = CompositeModel(EFFECTS, 10, fixed_theta={"delay": {"delay_s": float(delay_s)}}).fit([record])
        held[float(delay_s)] = model.train_rms_um
    assert free.train_rms_um <= min(held.values()) * 1.001, (free.theta, free.train_rms_um, held)

