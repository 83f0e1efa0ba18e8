"""Discovery at other magnitudes than the fixtures' (the same physics, smaller or larger): the
hidden effect still ranks first and refining with it at least halves the held-out error; where a
small effect is ambiguous, the experiment the diagnosis names tells the two apart."""

from __future__ import annotations

import warnings

import pytest

from service.science.discovery.composite import CompositeModel
from service.science.discovery.diagnosis import diagnose

OTHER_MAGNITUDES = [
    ("creep", {"axes.y.piezo.creep.scale": 0.3, "axes.z.piezo.creep.scale": 0.3}),
    ("asymmetry", {"axes.y.piezo.asymmetry.scale": 4.0, "axes.z.piezo.asymmetry.scale": 4.0}),
    ("delay", {"daq.latency.samples": 15}),
]

pytestmark = pytest.mark.slow  # a diagnosis takes seconds


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


@pytest.mark.parametrize(("bench", "overrides"), OTHER_MAGNITUDES, ids=[b for b, _ in OTHER_MAGNITUDES])
def test_hidden_effect_found_at_another_magnitude(bench, overrides, sweeps):
    record = sweeps(bench, seed=2, overrides=overrides)["y"]
    d = diagnose([record])
    ranked = [(c["effect"], round(c["score"], 2)) for c in d["candidates"]]
    assert d["verdict"] == "missing_effect" and ranked[0][0] == bench, ranked
    after = CompositeModel([bench]).fit([record]).evaluate([record])["validation_rms_um"]
    assert after <= 0.5 * d["residual_rms_um"], (d["residual_rms_um"], after)


def test_small_rate_dependence_is_told_from_delay_by_the_named_experiment(sweeps):
    """A rate dependence at 0.3× looks like a delay on 1–100 Hz: the diagnosis says so and names a
    higher-frequency sweep; with that sweep's data, rate dependence leads clearly (added to the
    model, the best delay leaves 1.42× its held-out error: 1.5× and more while the delay's search
    could not reach between its grid points)."""
    overrides = {"axes.y.piezo.rate_dependence.scale": 0.3, "axes.z.piezo.rate_dependence.scale": 0.3}
    record = sweeps("rate_dependence", seed=0, overrides=overrides)["y"]
    amb = diagnose([record])["ambiguity"]
    assert amb and set(amb["effects"]) == {"delay", "rate_dependence"}, amb
    extra = sweeps("rate_dependence", seed=1, plan=amb["experiment"], overrides=overrides)["y"]
    d = diagnose([record, extra])
    held_out = {c["effect"]: c["expected_rms_um"] for c in d["candidates"]}
    assert d["candidates"][0]["effect"] == "rate_dependence" and d["ambiguity"] is None
    assert held_out["delay"] > 1.3 * held_out["rate_dependence"], held_out
