"""The paper's models on the emulated bench: dynamic PI beats static PI where the physics is rate dependent."""
from __future__ import annotations

import numpy as np
import pytest

from service.science.models import DynamicPI, StaticPI
from service.reports.reproduction import render_markdown, sweep_series


def _mean_rms(model, loops) -> float:
    return float(np.mean([np.sqrt(np.mean((s.x_um - model.predict(s)) ** 2)) for s in loops]))


@pytest.fixture(scope="module")
def rate_dependent_loops():
    return sweep_series("rate_dependence", seed=3)


def test_dynamic_pi_beats_static_pi_on_rate_dependent_emulated_data(rate_dependent_loops):
    """Both fitted jointly on 1/10/50/100 Hz loops of the rate_dependence bench (dielectric
    relaxation in the emulated stack, not the dynamic-PI form). Measured: 4.6× lower mean RMS on
    both axes (Y 0.152 → 0.033 µm, Z 0.201 → 0.044 µm). Asserted: at least 3×."""
    for axis, loops in rate_dependent_loops.items():
        static = _mean_rms(StaticPI().fit(loops), loops)
        dynamic = _mean_rms(DynamicPI().fit(loops), loops)
        assert static / dynamic > 3.0, (axis, static, dynamic)


def test_dynamic_pi_gains_nothing_on_rate_independent_emulated_data():
    """On the base bench (no rate dependence) the extra rate parameters buy < 10 % (measured ≈ 0.3 %)."""
    for axis, loops in sweep_series("base", seed=3).items():
        static = _mean_rms(StaticPI().fit(loops), loops)
        dynamic = _mean_rms(DynamicPI().fit(loops), loops)
        assert dynamic <= static + 1e-12 and static / dynamic < 1.1, (axis, static, dynamic)


def test_reproduction_table_has_every_model_and_the_papers_figures():
    fake = {axis: {"rms_um": {m: {f"{f:g} Hz": 0.1 for f in (1.0, 10.0, 50.0, 100.0)}
                              for m in ("dynamic_joint", "dynamic_two_stage", "dynamic_pso", "grpi", "static")},
                   "fit_s": {"static": 0.01}} for axis in ("y", "z")}
    text = render_markdown(fake)
    assert "| Y | 10 Hz | 0.1000 | 0.1000 | 0.1000 | 0.1000 | 0.1000 | 0.0586 / 0.0933 / 0.0991 |" in text
    assert "| Z | 100 Hz |" in text and "0.1039 / 0.1326 / 0.1513" in text
