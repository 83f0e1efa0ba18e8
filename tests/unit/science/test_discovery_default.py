"""Discovery on the default bench (several effects at realistic size): following the diagnosis
(top physical candidate each time, then hysteresis capacity while the model is not at the noise
floor) must reach a 'complete' verdict at the noise floor, with every step's evidence in words,
and each step must lower the held-out error. The final validation RMS is within 2× the noise
floor at 1, 10, 50 and 100 Hz, on Y's own blocks and on those where only Z moves.
"""

from __future__ import annotations

import re
import warnings

import pytest

from service.science.discovery.loop import discovery_run, stops_at_ambiguity

pytestmark = pytest.mark.slow  # the longest test: a whole discovery run on the default bench


def test_default_bench_discovery_converges(sweeps):
    warnings.simplefilter("ignore")
    record = sweeps("default", seed=0)["y"]
    steps = discovery_run([record], continue_past_ambiguity=True)
    # without continue_past_ambiguity the loop stops at the first step whose two leading look-alikes
    # explain the data alike, naming the sweep; with it, the loop adds the leading one and goes on
    stops = [k for k, s in enumerate(steps) if stops_at_ambiguity(s["diagnosis"], False) is not None]
    assert stops and stops[0] == 0  # the stack's asymmetry and the gauge's bow bend the first loop alike
    need = stops_at_ambiguity(steps[0]["diagnosis"], False)
    assert set(need["effects"]) == {"asymmetry", "sensor_nonlinearity"}
    experiment = need["experiment"]  # more rates and cycles part them, over the drive range measured
    assert experiment["waveform"] == "sine" and max(experiment["frequencies_hz"]) > 100.0
    assert experiment["cycles"] >= 10 and experiment["v_min"] < experiment["v_max"]
    assert steps[1]["effects"][-1] == need["effects"][0]  # the leading one, added
    stopped = discovery_run([record])
    assert [s["effects"] for s in stopped] == [s["effects"] for s in steps[:1]]
    rms = [s["diagnosis"]["residual_rms_um"] for s in steps]
    assert steps[-1]["diagnosis"]["verdict"] == "complete"
    assert len(steps) >= 4  # several effects are hidden
    added = [s["effects"][-1] for s in steps[1:]]
    assert len(set(added)) == len(added)
    assert {"asymmetry", "dynamics", "cross_coupling"} <= set(added)
    for before, after in zip(rms, rms[1:]):
        assert after < before, rms
    assert rms[-1] <= 0.3 * rms[0], rms
    for s in steps[:-1]:
        d = s["diagnosis"]
        if d["verdict"] == "missing_effect":
            top = next(c for c in d["candidates"] if c["kind"] == "physical")
            assert top["high"] and re.search(r"\d", top["evidence"]) and top["effect"] in top["evidence"]
        else:  # physics complete, not at the floor: capacity is added, and said to be capacity
            assert not d["at_noise_floor"] and "NOT at the noise floor" in d["verdict_text"]
            assert "capacity" in d["answer"]["text"]
    capacity = [e for e in added if e == "operators"]
    assert not capacity or added[-1] == "operators"  # capacity only once physics is complete
    last = steps[-1]["diagnosis"]
    assert last["verdict"] == "complete" and last["at_noise_floor"], last["verdict_text"]
    final = steps[-1]["per_block"]
    # Y's own blocks (0–3) and those where only Z moves (4–7, Y sees only the coupling)
    assert len(final) == 8 and all(b["validation_rms_um"] <= 2 * b["noise_floor_um"] for b in final), final
