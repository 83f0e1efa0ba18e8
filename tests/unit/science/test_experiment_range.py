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
    step = EFFECTS["creep"].separated_from["drift"][1]  # creep from drift: a step-hold on a default plan's 0–120 V
    assert step["waveform"] == "step" and max(step["levels_v"]) > 3.6
    body = experiment_body([_Driven(lo_v, hi_v)], ["y"], **step)
    assert (body["v_min"], body["v_max"]) == (lo_v, hi_v)
    assert all(lo_v <= level <= hi_v for level in body["levels_v"])
    # the same share of the range as on 0–120 V: 100 V and 20 V are 5/6 and 1/6 of it
    shares = [(level - lo_v) / (hi_v - lo_v) for level in body["levels_v"]]
    assert shares == pytest.approx([(v - 0.0) / 120.0 for v in step["levels_v"]], abs=0.05 / (hi_v - lo_v) + 1e-9)
    plan = plan_from_dict({**body, "sample_rate_hz": 1000.0, "axes": ("y",)})
    assert build(plan, max_rate_v_per_s=1e6).u_v["y"].max() <= hi_v  # a plan that runs within the range
