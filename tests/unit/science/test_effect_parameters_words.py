"""Every effect whose words print a fitted figure carries that figure as a number (issue 39: Discover's
"Effects found" showed rate dependence's parameters as "–", ``{"rate_dependence": {}}``, while the report
printed "operator-rate weights sum … nm·s/V"): the loop's ``final_parameters`` and the report's words
are one computation, each name with its unit."""

from __future__ import annotations

import numpy as np
import pytest

from service.science.data.units import plain
from service.science.effects import EFFECTS

SCALES = {"time_scale_s": 10.0, "u_scale_v": 100.0, "stroke_um": 100.0}


@pytest.mark.parametrize(
    ("effect", "values", "expected", "printed"),
    [
        (
            "rate_dependence",
            {"rate_operator_lag_um_s_per_v": np.array([1.5e-3, -0.25e-3, 0.5e-3])},
            {"operator_rate_weights_sum_nm_s_per_v": 1.75},
            "operator-rate weights sum 1.75 nm·s/V",
        ),
        ("temperature", {"temperature_um_per_k": np.array([4e-3, 2.5e-3])}, {"gain_change_nm_per_k": 6.5}, "6.5 nm/K"),
        (
            "sensor_nonlinearity",
            {"gauge_bow_um": np.array([0.012, -0.0034])},
            {"gauge_bow_pct": 1.2, "s_bend_pct": -0.34},
            "gauge bow 1.2 % and S-bend -0.34 %",
        ),
    ],
)
def test_the_words_figures_are_the_parameters(effect, values, expected, printed):
    e = EFFECTS[effect]
    params = e.parameters({}, values, SCALES, 1.0)
    assert params == pytest.approx(expected)
    assert all(e.units.get(name) for name in params), e.units  # each with its unit
    words = e.describe({}, values)
    assert printed in words, words
    for value in params.values():  # every number the stored parameters hold is in the words, as printed
        assert plain(value) in words or f"{value:.3g}" in words, (value, words)


def test_an_unfitted_effect_has_neither_words_nor_parameters():
    for effect in ("rate_dependence", "temperature", "sensor_nonlinearity"):
        assert EFFECTS[effect].parameters({}, {}, SCALES, 1.0) == {} and EFFECTS[effect].describe({}, {}) == ""


def test_asymmetrys_stored_weights_are_its_parameters_with_units():
    """Discover's "Effects found" showed asymmetry's parameters as "–" although the stored model holds
    ``coef.asymmetry_um``: its four weights are its parameters, the output each column adds at the full
    drive scale in nm and the gauge's sign, each with its unit."""
    e = EFFECTS["asymmetry"]
    stored = {"asymmetry_um": [12.052540559599436, -11.73341694065384, -0.32796721328100503, 1.6654131432633035]}
    params = e.parameters({}, stored, SCALES, -1.0)
    assert list(params) == ["asymmetry_u2_nm", "asymmetry_u3_nm", "asymmetry_s2_nm", "asymmetry_us_nm"]
    assert list(params.values()) == pytest.approx([-12052.54, 11733.42, 327.97, -1665.41], abs=0.01)
    assert all(e.units[name] == "nm" for name in params)
    assert e.parameters({}, {}, SCALES, 1.0) == {}


def test_a_lag_in_a_block_without_a_frequency_is_named_as_such():
    """A step-hold (or an import's block) has no frequency: its lag is keyed "record" by the breakdown,
    which the evidence printed as "record Hz: -122 µs"."""

    sig = {"lag_ms": -0.458, "lag_ms_by_frequency": {"record": -0.122, "100": -0.187}, "lag_ms_spread": 0.72}
    words = EFFECTS["delay"].evidence(sig, {})
    assert "record Hz" not in words and "a block without a frequency: -122 µs, 100 Hz: -187 µs" in words, words
