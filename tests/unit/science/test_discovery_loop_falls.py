"""Issue 37 §3, a loop whose error only falls: an added effect that raises the held-out RMS is not
kept, every step is scored like for like when an experiment adds data, and an experiment is cut to
what the bench allows (or skipped) rather than refused. Short emulated sweeps of the default bench
(10 and 100 Hz, 3 cycles) keep each fit to about a second."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from service.lab.emulated import open_bench, sweep_records
from service.science.discovery.composite import fit_composite
from service.science.discovery.identifiability import not_testable
from service.science.discovery.like_for_like import like_for_like
from service.science.discovery.loop import (
    discovery_step,
    held_out_rms_um,
    needed_experiment,
    next_effect,
    not_kept,
    still_separates,
    try_step,
)
from service.science.discovery.rests import LineFree
from service.science.effects import EFFECTS
from service.science.errors import FieldError
from service.usecases.acquire import BenchExperiments, plan_sweep, planned_records, runnable_sweep
from service.usecases.discover_experiments import ExperimentPolicy

#: the sweep the diagnosis names to tell delay, dynamics and rate dependence apart (diagnosis.SEPARATING)
FASTER = {"axes": ["z"], "waveform": "sine", "frequencies_hz": [100.0, 150.0, 200.0], "cycles": 10, "v_max": 120.0}


@pytest.fixture(scope="module")
def default_y():
    warnings.simplefilter("ignore")
    return sweep_records("default", 0, frequencies_hz=(10.0, 100.0), cycles=3)["y"]


def test_a_rise_is_said_in_nm_and_only_a_rise():
    rejected = not_kept("cross_coupling", 0.077, 0.102)
    assert rejected["text"] == "adding cross_coupling raised the held-out RMS from 77 nm to 102 nm: not kept"
    assert (rejected["before_rms_um"], rejected["held_out_rms_um"]) == (0.077, 0.102)
    assert not_kept("creep", 0.077, 0.077) is None and not_kept("creep", 0.077, 0.039) is None


def _wandering(record, amp_um: float):
    """``record`` with a level that rises by ``amp_um`` over each block's training cycles and falls
    back by twice that over its held-out ones: what creep's log-time fits on the training cycles and
    the held-out ones contradict."""
    w = np.zeros(len(record.x_um))
    for s in record.splits:
        (a, cut), b = s.train, s.held_out[1]
        w[a:cut], w[cut:b] = np.linspace(0.0, amp_um, cut - a), np.linspace(amp_um, -amp_um, b - cut)
    return record.with_x(record.x_um + w)


def test_an_added_effect_that_raises_the_held_out_rms_is_not_kept(default_y):
    """Creep fitted on a level that rises over the training cycles and falls over the held-out ones
    extrapolates the rise (measured: 186 → 193 nm): try_step says so and diagnoses nothing; an
    effect that lowers the held-out RMS (asymmetry) is a step."""
    records = [_wandering(default_y, 0.2)]
    base = fit_composite(records, [], 10)
    before = held_out_rms_um(records, base)
    model, step, rejected = try_step(LineFree.of(records), ["creep"], "creep", 10, base.theta, before)
    after = held_out_rms_um(records, model)
    assert step is None and rejected["effect"] == "creep", (before, after)
    assert rejected["held_out_rms_um"] == pytest.approx(after, rel=1e-12) and after > before + 0.003
    assert rejected["text"].startswith("adding creep raised the held-out RMS from 18")
    _, kept, none = try_step(LineFree.of(records), ["asymmetry"], "asymmetry", 10, base.theta, before)
    assert none is None and kept["diagnosis"]["residual_rms_um"] < before


def test_the_loop_passes_over_what_it_did_not_keep(default_y):
    """next_effect with the effects tried and not kept excluded: the next candidate of the same
    diagnosis (the default bench's first names several), and None once none is left."""
    _, step = discovery_step(LineFree.of([default_y]), [], 10)
    d = step["diagnosis"]
    tried = []
    while (effect := next_effect(d, tried)) is not None:
        assert effect not in tried
        tried.append(effect)
    claimed = [c["effect"] for c in d["candidates"] if c["kind"] == "physical" and c["claimed"]]
    assert d["verdict"] == "missing_effect" and len(claimed) >= 2 and set(claimed) <= set(tried), (claimed, tried)


def test_every_step_is_scored_on_the_same_data(default_y):
    """like_for_like: each step's effects refitted on the enlarged records, scored on the same held-out
    cycles; the first records alone give the figure on the original data. A step that another
    shares the effect set of gets the same figures; a fitted model is scored as it is."""
    extra = sweep_records("default", 1, frequencies_hz=(50.0,), cycles=3)["y"]
    records = [default_y, extra]
    base = fit_composite([default_y], [], 10)
    steps = [([], {}), (["asymmetry"], {}), ([], {})]
    figures = like_for_like(LineFree.of(records), 1, steps, 10)
    assert figures[0] == figures[2]
    alone = like_for_like(LineFree.of([default_y]), 1, [([], {})], 10)[0]
    assert alone["like_for_like_rms_um"] == pytest.approx(held_out_rms_um([default_y], base), rel=1e-9)
    assert alone["original_data_rms_um"] == alone["like_for_like_rms_um"]
    # on both records: a different figure from the original data's, and asymmetry lowers both
    assert abs(figures[0]["like_for_like_rms_um"] - figures[0]["original_data_rms_um"]) > 1e-4
    assert figures[1]["like_for_like_rms_um"] < figures[0]["like_for_like_rms_um"]
    assert figures[1]["original_data_rms_um"] < figures[0]["original_data_rms_um"]
    both = fit_composite(records, ["asymmetry"], 10)
    given = like_for_like(LineFree.of(records), 1, steps[1:2], 10, fitted={("asymmetry",): both})[0]
    assert given["like_for_like_rms_um"] == pytest.approx(held_out_rms_um(records, both), rel=1e-12)
    assert np.isfinite(given["original_data_rms_um"])


def test_an_experiment_is_cut_to_what_the_bench_allows():
    """The default bench's Z axis (first resonance 290.7 Hz) refuses 150 and 200 Hz as POST
    /api/sweeps does; cut, the sweep keeps 100 Hz and adds the largest whole hertz it allows."""
    bench = open_bench("default", 0)
    with pytest.raises(FieldError) as refused:
        plan_sweep(bench, FASTER)
    assert refused.value.field == "frequencies_hz" and "290.7 Hz" in refused.value.message
    body, cuts = runnable_sweep(bench, FASTER)
    assert body["frequencies_hz"] == [100.0, 145.0] and len(cuts) == 1 and "145.3 Hz" in cuts[0]
    plan_sweep(bench, body)  # accepted as it is
    assert runnable_sweep(bench, {**FASTER, "axes": ["y"]}) == ({**FASTER, "axes": ["y"]}, [])  # Y: 482.6 Hz
    step = {"axes": ["y"], "waveform": "step", "levels_v": [100.0, 20.0, 200.0], "hold_s": 1.0}
    body, cuts = runnable_sweep(bench, step)
    assert body["levels_v"] == [100.0, 20.0, 120.0] and cuts == ["levels_v → 100, 20, 120 V"]


def test_a_cut_experiment_runs_only_if_it_still_separates(default_y):
    """Data up to 100 Hz: a faster sweep cut to 145 Hz still separates (≥ 1.1 × 100 Hz); cut to
    105 Hz it does not; a step sweep cut to one level does not change the drive."""
    records = [default_y]
    assert still_separates(FASTER, {**FASTER, "frequencies_hz": [100.0, 145.0]}, records) is None
    why = still_separates(FASTER, {**FASTER, "frequencies_hz": [100.0, 105.0]}, records)
    assert why is not None and "100 Hz" in why and "105 Hz" in why
    step = {"waveform": "step", "levels_v": [100.0, 20.0]}
    assert still_separates(step, {**step, "levels_v": [100.0, 100.0]}, records) is not None
    assert still_separates(step, step, records) is None


def test_a_cut_test_of_an_effect_is_judged_by_that_effects_rule():
    """A walk's dead end: on Z (0–120 V data up to 100 Hz, 37.7 kV/s) the slew-limit test asks for
    150 Hz; cut to 145 Hz at 0–120 V its drive reaches 54.7 kV/s, under the half of the amplifier's
    111 kV/s rating the rule needs, and the data it adds still cannot test the effect. Judged by
    slew_limit's own rule, the cut sweep runs over the whole 0–150 V range instead (68 kV/s)."""
    warnings.simplefilter("ignore")
    z = sweep_records("default", 0, frequencies_hz=(10.0, 100.0), cycles=3)["z"]
    need = not_testable("slew_limit", [z])
    assert need is not None and max(need["experiment"]["frequencies_hz"]) == 150.0
    bench = open_bench("default", 0)
    rule = EFFECTS["slew_limit"].untestable
    short, _ = runnable_sweep(bench, need["experiment"])
    assert rule([z, *planned_records(bench, short, "z")]) is not None  # the plain cut: still untestable
    body, cuts, why = ExperimentPolicy(fit=BenchExperiments(bench)).runnable(need, [z], effect="slew_limit")
    assert why is None and (body["v_min"], body["v_max"]) == (0.0, 150.0) and max(body["frequencies_hz"]) == 145.0
    assert "0–150 V" in cuts[0] and "slew_limit" in cuts[0]
    assert rule([z, *planned_records(bench, body, "z")]) is None  # what it adds tests the effect
    plan_sweep(bench, body)  # and POST /api/sweeps accepts it


def test_an_experiment_the_bench_cannot_run_is_never_the_loops_next_sweep():
    """A discover job on the default bench's Z failed with "'NoneType' object has no attribute 'get'":
    the slew-limit test, which the bench could not run (``not_runnable_here``, its body None), was
    taken as the next sweep. It is passed over, and the next one the bench can run is taken."""
    runnable = {"axes": ["z"], "waveform": "sine", "frequencies_hz": [1.0], "cycles": 60}
    d = {
        "verdict": "complete",
        "noise_floor_um": 3e-3,
        "at_noise_floor": False,
        "candidates": [],
        "ambiguity": None,
        "not_testable": [
            {
                "effect": "slew_limit",
                "kind": "physical",
                "reason": "too slow",
                "experiment": None,
                "experiment_asked": {"frequencies_hz": [150.0]},
                "not_runnable_here": "cut, it no longer tests it",
            },
            {"effect": "temperature", "kind": "physical", "reason": "too short", "experiment": runnable},
        ],
    }
    need = needed_experiment(d, stopping=True)
    assert need == {"effects": ["temperature"], "reason": "too short", "experiment": runnable}
    d["not_testable"].pop()
    assert needed_experiment(d, stopping=True) is None
