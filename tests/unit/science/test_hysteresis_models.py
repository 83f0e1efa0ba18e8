"""Model contract: parameter recovery, JSON round trips, rate dependence, real data."""

import json

import numpy as np
import pytest

from service.perf.identification import lagged_pi_loops
from service.science.data.record import Record
from service.science.data.signals import biased_sine, multi_sine
from service.science.discovery.registry import MODELS, model_from_dict
from service.science.fitting.metrics import fit_metrics
from service.science.models import GRPI, PAPER_MODELS, DynamicPI, StaticPI
from tests.support.pi_truths import FS, WEIGHTS, dynamic_truth, grpi_truth, static_truth
from tests.support.realdata import MODEL_VI_DO as REAL


def loops(frequencies=(1.0, 10.0, 50.0, 100.0), cycles=5, analytic=True):
    out = []
    for f in frequencies:
        w = biased_sine(f, cycles, FS)
        s = Record.from_waveform(w, label=f"{f:g} Hz") if analytic else Record(w.value, None, FS, label=f"{f:g} Hz")
        out.append(s)
    return out


def record(truth, drives):
    return [s.with_x(truth.predict(s)) for s in drives]


def test_registry_names():
    assert PAPER_MODELS == {"static_pi": StaticPI, "dynamic_pi": DynamicPI, "grpi": GRPI}
    assert set(MODELS) == set(PAPER_MODELS) | {"composite", "hysterons"}


def test_static_pi_recovers_weights_and_offset():
    truth = static_truth()
    drives = [
        Record.from_waveform(biased_sine(1.0, 3, FS)),
        Record.from_waveform(multi_sine([2.0, 9.0], [40.0, 12.0], FS, 1.0)),
    ]
    model = StaticPI().fit(record(truth, drives))
    np.testing.assert_array_equal(model.thresholds_v, truth.thresholds_v)  # 0, 6, …, 54 V from max(u)=120
    np.testing.assert_allclose(model.weights_um_per_v, WEIGHTS, rtol=1e-6)
    assert model.offset_um == pytest.approx(0.7, rel=1e-6)
    assert model.train_rms_um < 1e-9


def test_static_pi_weights_respect_nonnegativity():
    """A loop whose best unconstrained fit needs a negative weight: the bound must hold."""
    truth = static_truth()
    data = record(truth, loops((1.0,), cycles=2))[0]
    x = data.x_um - 0.02 * np.maximum(data.u_v - 100.0, 0.0)  # saturation at the top
    model = StaticPI().fit(data.with_x(x))
    assert np.all(model.weights_um_per_v >= 0.0)
    assert np.any(model.weights_um_per_v == 0.0)


@pytest.mark.parametrize("analytic", [True, False], ids=["commanded-derivatives", "savgol-derivatives"])
def test_dynamic_pi_recovers_all_parameters_jointly(analytic):
    truth = dynamic_truth()
    model = DynamicPI().fit(record(truth, loops(cycles=2, analytic=analytic)))
    np.testing.assert_allclose(model.weights_um_per_v, truth.weights_um_per_v, rtol=1e-6)
    np.testing.assert_allclose(model.alpha_um_per_v2_s, truth.alpha_um_per_v2_s, rtol=1e-6)
    np.testing.assert_allclose(model.beta_um_per_v2_s2, truth.beta_um_per_v2_s2, rtol=1e-6)
    assert model.offset_um == pytest.approx(truth.offset_um, rel=1e-6)


def test_grpi_recovers_envelope_and_weights():
    """Noise-free GRPI data over 4 loops: (a1, a2, b1, b2) back to 1e-6 relative (measured ~1e-15)."""
    truth = grpi_truth()
    model = GRPI().fit(record(truth, loops(cycles=2)))
    np.testing.assert_allclose(model.envelope, truth.envelope, rtol=1e-6)
    np.testing.assert_allclose(model.weights_um_per_v, WEIGHTS, rtol=1e-6)
    assert model.offset_um == pytest.approx(0.2, rel=1e-6)


def test_grpi_at_unit_envelope_is_the_static_pi():
    static = static_truth()
    grpi = GRPI.from_dict({**static.to_dict(), "model": "grpi", "a1": 1.0, "a2_s": 0.0, "b1": 1.0, "b2_s": 0.0})
    s = loops((10.0,))[0]
    np.testing.assert_allclose(grpi.predict(s), static.predict(s), rtol=0, atol=1e-13)


@pytest.mark.parametrize("truth_fn", [static_truth, dynamic_truth, grpi_truth])
def test_json_round_trip_gives_identical_predictions(truth_fn):
    truth = truth_fn()
    model = type(truth)().fit(record(truth, loops((1.0, 100.0), cycles=2)))
    text = json.dumps(model.to_dict())
    again = model_from_dict(json.loads(text))
    assert type(again) is type(model)
    s = Record(multi_sine([7.0, 31.0], [35.0, 9.0], FS, 0.4).value, None, FS)
    np.testing.assert_array_equal(again.predict(s), model.predict(s))
    assert again.to_dict() == model.to_dict()


@pytest.mark.parametrize("name", sorted(PAPER_MODELS))
def test_a_negative_or_bipolar_drive_counts_the_operators_from_its_lowest_volt(name):
    """Measured data may come from a bipolar amplifier: the operators count from the lowest drive,
    so a record shifted by −150 V (−150…−30 V) fits exactly like the same loop at 0…120 V."""
    truth = static_truth()
    drives = [Record.from_waveform(biased_sine(1.0, 3, FS)), Record.from_waveform(biased_sine(10.0, 3, FS))]
    shifted = [
        Record(s.u_v - 150.0, truth.predict(s), FS, du_v_per_s=s.derivatives()[0], ddu_v_per_s2=s.derivatives()[1])
        for s in drives
    ]
    model = PAPER_MODELS[name]().fit(shifted)
    assert model.u_origin_v == -150.0
    np.testing.assert_array_equal(model.thresholds_v, truth.thresholds_v)  # 0, 6, …, 54 V above −150 V
    assert model.train_rms_um < 1e-6
    again = model_from_dict(json.loads(json.dumps(model.to_dict())))
    np.testing.assert_array_equal(again.predict(shifted[0]), model.predict(shifted[0]))
    if name == "static_pi":
        np.testing.assert_allclose(model.weights_um_per_v, WEIGHTS, rtol=1e-6)
        u_back = model.inverse(truth.predict(drives[0]), method="numerical", u_limits_v=(-150.0, -30.0))
        np.testing.assert_allclose(u_back, drives[0].u_v - 150.0, atol=1e-6)
        bipolar = Record(2.5 * drives[0].u_v - 150.0, truth.predict(drives[0]), FS)  # −150…+150 V
        assert StaticPI().fit(bipolar).thresholds_v[-1] == pytest.approx(135.0)  # 0…135 V above −150 V


def test_models_refuse_misuse():
    with pytest.raises(RuntimeError, match="not fitted"):
        StaticPI().predict(np.linspace(0, 120, 100))
    with pytest.raises(ValueError, match="expected model 'grpi'"):
        GRPI.from_dict(static_truth().to_dict())
    with pytest.raises(ValueError, match="sample_rate_hz"):
        dynamic_truth().predict(np.linspace(0, 120, 100))
    with pytest.raises(ValueError, match="u_v contains 1 NaN"):
        static_truth().predict(np.array([0.0, np.nan, 1.0]))


def test_dynamic_beats_static_on_lagged_pi():
    """PI behind a 0.3 ms first-order lag (not the dynamic-PI form), 1/10/50/100 Hz jointly.

    Measured static/dynamic RMS: 4.88 overall; per loop 5.5, 2.9, 4.5, 5.3.
    """
    data = lagged_pi_loops(tau_s=3e-4)
    static, dynamic = StaticPI().fit(data), DynamicPI().fit(data)
    assert static.train_rms_um / dynamic.train_rms_um > 4.0
    for s in data:
        ratio = fit_metrics(s.x_um, static.predict(s))["rms_um"] / fit_metrics(s.x_um, dynamic.predict(s))["rms_um"]
        assert ratio > 2.5, s.label


def test_static_pi_on_real_micromanipulator_needs_the_offset():
    """yan9a Model_Vi_Do.dat (200 Hz, 1 Hz drive 0–3.6 V, sensor zero ≈ −120 µm).

    Measured: fit 97.1 % (RMS 0.46 µm) with the offset; without it the fit is meaningless.
    """
    raw = np.loadtxt(REAL)
    s = Record(raw[:, 0], raw[:, 4], 200.0, label="yan9a")
    with_offset = fit_metrics(s.x_um, StaticPI().fit(s).predict(s))
    without = fit_metrics(s.x_um, StaticPI(fit_offset=False).fit(s).predict(s))
    assert with_offset["fit_percent"] > 96.0
    assert with_offset["rms_um"] < 0.6
    assert without["fit_percent"] < 0.0
    assert fit_metrics(s.x_um, DynamicPI().fit(s).predict(s))["rms_um"] <= with_offset["rms_um"]
