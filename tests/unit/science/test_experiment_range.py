"""An experiment the diagnosis names for a record spans that record's own drive range (a new user's
walk: a record driven 0–3.6 V on another stage was told to step to 100 and 20 V, this bench's range)."""

from __future__ import annotations

import numpy as np
import pytest

from service.science.data.plans import build, plan_from_dict
from service.science.discovery.identifiability import experiment_body
from service.science.effects import EFFECTS


class _Driven:
    """A record as experiment_body reads it: only its drive (V)."""

    def __init__(self, lo_v: float, hi_v: float):
        self.u_v = np.concatenate([np.linspace(lo_v, hi_v, 200), np.linspace(hi_v, lo_v, 200)])


@pytest.mark.parametrize("lo_v, hi_v", [(0.0, 3.6), (-150.0, 150.0), (0.0, 120.0)])
def test_a_step_experiment_is_on_the_records_range_and_builds(lo_v, hi_v):
    step = EFFECTS["creep"].separated_from["drift"][1]  # creep from drift: a step-hold up and down
    assert step["waveform"] == "step" and "levels_v" not in step  # the effect knows shares, not the stage's volts
    body = experiment_body([_Driven(lo_v, hi_v)], ["y"], **step)
    assert (body["v_min"], body["v_max"]) == (lo_v, hi_v) and "level_shares" not in body
    assert all(lo_v <= level <= hi_v for level in body["levels_v"])
    # each level at its share of the record's range, to the 0.1 V the body is rounded to
    shares = [(level - lo_v) / (hi_v - lo_v) for level in body["levels_v"]]
    assert shares == pytest.approx(step["level_shares"], abs=0.05 / (hi_v - lo_v) + 1e-9)
    plan = plan_from_dict({**body, "sample_rate_hz": 1000.0, "axes": ("y",)})
    assert build(plan, max_rate_v_per_s=1e6).u_v["y"].max() <= hi_v  # a plan that runs within the range


def test_a_step_experiment_without_a_recorded_drive_is_on_a_default_plan():
    """Records without a drive (a position-only import): the shares are placed on a default plan's
    0–120 V, 5/6 and 1/6 of it 100 and 20 V."""
    step = EFFECTS["creep"].separated_from["drift"][1]
    body = experiment_body([], ["y"], **step)
    assert body["levels_v"] == [100.0, 20.0, 100.0, 20.0] and "v_min" not in body


def test_an_effect_giving_its_steps_in_volts_fails_the_contract():
    """A plug-in effect with ``levels_v`` in its step sweep is refused by the conformance check, naming the field."""
    from service.science.effects.conformance import _step_levels_failures

    assert _step_levels_failures("sweep", {"waveform": "step", "levels_v": [100.0, 20.0]})[0].check == "sweep"
    assert _step_levels_failures("sweep", {"waveform": "step", "level_shares": [1.2]})
    assert _step_levels_failures("sweep", {"waveform": "step", "level_shares": [0.8, 0.2]}) == []
    assert _step_levels_failures("sweep", {"waveform": "sine", "frequencies_hz": [1.0]}) == []


class _Blocks:
    """A record as the rates are read: its own axis's blocks at ``rates_hz``."""

    def __init__(self, *rates_hz: float):
        self.u_v = np.zeros(0)
        self._splits = [type("Split", (), {"block": {"frequency_hz": f}})() for f in rates_hz]

    def splits_of(self, own_axis_only=False):
        return self._splits


@pytest.mark.parametrize(
    "rates_hz, asked_hz", [((1.0, 10.0, 50.0, 100.0), [100.0, 150.0, 200.0]), ((200.0,), [200.0, 300.0, 400.0])]
)
def test_a_separating_sweep_asks_for_rates_above_the_datas(rates_hz, asked_hz):
    """Dynamics against rate dependence: a sweep from the data's fastest rate to twice it (a walk was told to
    run 100–200 Hz to separate them on a record already driven at 200 Hz)."""
    body = experiment_body([_Blocks(*rates_hz)], ["y"], **EFFECTS["dynamics"].separated_from["rate_dependence"][1])
    assert body["frequencies_hz"] == asked_hz and "rate_multiples" not in body
