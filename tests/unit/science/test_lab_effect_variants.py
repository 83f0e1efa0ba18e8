"""Issue 38 §3 on the emulator: each lab effect's variant bench (a standard characterisation of axis Y,
1/10/50/100 Hz, 5 cycles, the emulator's own physics) has its effect named first and claimed by the
diagnosis of a hysteresis model, which then removes a share of the excess above the noise floor."""

from __future__ import annotations

import warnings

import pytest

from service.science.discovery.diagnosis import diagnose

pytestmark = pytest.mark.slow  # a sweep and a diagnosis per bench (30–60 s each)


@pytest.mark.parametrize(
    ("bench", "share"),
    [("line_disturbance", 0.0), ("gain_change", 0.5), ("slew_limit", 0.9)],
)
def test_the_variant_bench_has_its_effect_named_first(bench, share, sweeps):
    """Measured: the line 0 (it is out of the record before the model is judged: 5.79 nm held out against
    3.13 nm of floor), the gain change 0.78 (9.48 → 5.19 nm), the rate limit 0.9995 (213 → 5.65 nm)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = diagnose([sweeps(bench)["y"]])
    top = next(c for c in d["candidates"] if c["kind"] == "physical")
    assert (top["effect"], top["claimed"]) == (bench, True), [(c["effect"], c["claimed"]) for c in d["candidates"]]
    assert top["excess_removed"] >= share
