"""Identification: bounded LS over blocks, the paper's two-stage and PSO procedures, metrics."""

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from service.perf.identification import run_identification_benchmark
from service.science.data.record import Record
from service.science.data.signals import biased_sine
from service.science.fitting.lsq import Block, solve_blocks, stack_blocks
from service.science.fitting.metrics import fit_metrics
from service.science.fitting.pso import pso_minimize
from service.science.models import GRPI, DynamicPI, StaticPI, equal_thresholds
from service.science.models.contract import Drive
from service.science.models.procedures import evaluate, fit_dynamic_pi_pso, fit_dynamic_pi_two_stage, identify
from tests.support.pi_truths import FS, WEIGHTS, dynamic_truth


@pytest.fixture(scope="module")
def dynamic_data():
    truth = dynamic_truth()
    drives = [Record.from_waveform(biased_sine(f, 2, FS), label=f"{f:g} Hz") for f in (1.0, 10.0, 50.0, 100.0)]
    return truth, [s.with_x(truth.predict(s)) for s in drives]


def test_solve_blocks_matches_a_direct_bounded_solver():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(50_000, 6)) * np.array([1.0, 1e3, 1e-3, 5.0, 1.0, 1e6])
    b = a @ np.array([1.0, -2e-3, 300.0, 0.5, -1.0, 1e-6]) + rng.normal(0, 0.1, a.shape[0])
    blocks = [
        Block.make("pos", a[:, :3], lower=0.0),
        Block.make("box", a[:, 3:5], -0.2, 0.2),
        Block.make("free", a[:, 5]),
    ]
    got = solve_blocks(blocks, b)
    ref = lsq_linear(
        a, b, bounds=([0, 0, 0, -0.2, -0.2, -np.inf], [np.inf] * 3 + [0.2, 0.2, np.inf]), method="bvls", tol=1e-15
    )
    np.testing.assert_allclose(got.coef, ref.x, rtol=1e-7, atol=1e-12)
    assert got.values["pos"][1] == 0.0 and got.active[1]  # the negative coefficient sits on its bound
    np.testing.assert_array_equal(got.values["box"], [0.2, -0.2])
    np.testing.assert_allclose(got.residual, b - a @ got.coef, atol=1e-9)


def test_row_weights_and_zero_columns():
    rng = np.random.default_rng(2)
    a = rng.normal(size=(3000, 3))
    b = a @ np.array([1.0, 2.0, 3.0]) + rng.normal(0, 1, 3000)
    w = rng.uniform(0.1, 2.0, 3000)
    got = solve_blocks([Block.make("c", a), Block.make("dead", np.zeros((3000, 2)), lower=[0.5, -np.inf])], b, w)
    np.testing.assert_allclose(got.values["c"], np.linalg.lstsq(a * w[:, None], b * w, rcond=None)[0], rtol=1e-10)
    np.testing.assert_array_equal(got.values["dead"], [0.5, 0.0])


def test_a_direction_no_record_determines_keeps_its_weights_near_zero():
    """Two columns equal on the training rows to 1e-9 of their norm (the fine hysteron grid beside the
    gauge's bow: a stored model's weights of 3.6e7 µm cancelled there and predicted 1.6e16 µm from the
    rest before its first cycle). The damped solve splits the weight between them instead of
    cancelling, leaves the fit unchanged to 1e-9 of the noise, and predicts the rest row sanely."""
    rng = np.random.default_rng(4)
    drive = rng.uniform(0.0, 1.0, 40_000)
    twin = drive + 1e-9 * rng.normal(size=drive.size)
    target = 3.0 * drive + rng.normal(0, 1e-3, drive.size)
    got = solve_blocks([Block.make("weights", np.column_stack([drive, twin]))], target)
    exact = np.linalg.lstsq(np.column_stack([drive, twin]), target, rcond=None)[0]
    assert np.abs(exact).max() > 1e3  # the exact solve cancels: the hazard is real
    assert np.abs(got.coef).max() < 3.1 and abs(got.coef.sum() - 3.0) < 1e-3
    assert got.rms - 1e-3 < 1e-6
    rest_row = np.array([0.0, 1.0])  # the twins differ off the training rows (a virgin state)
    assert abs(rest_row @ got.coef) < 3.1


def test_subnormal_entries_are_flushed_and_change_no_coefficient():
    """Columns whose second half is a filter's ring-down tail (1e-310 .. 5e-324): the triangle is
    built from chunks with those entries at 0, and the weights are those of the design with zeros."""
    from service.science.fitting.lsq import SMALLEST_NORMAL, _chunks

    rng = np.random.default_rng(3)
    a = rng.normal(size=(20_000, 4))
    a[10_000:, :2] = rng.uniform(5e-324, 1e-310, size=(10_000, 2))
    b = a @ np.array([1.0, 2.0, -0.5, 0.25]) + rng.normal(0, 0.01, 20_000)
    chunks = list(_chunks([[a]], b, None))
    assert all(np.sum((c != 0.0) & (np.abs(c) < SMALLEST_NORMAL)) == 0 for c in chunks)
    assert sum(c.shape[0] for c in chunks) == 20_000
    zeroed = a.copy()
    zeroed[10_000:, :2] = 0.0
    got, ref = solve_blocks([Block.make("c", a)], b), solve_blocks([Block.make("c", zeroed)], b)
    np.testing.assert_array_equal(got.coef, ref.coef)


def test_ill_conditioned_designs_fall_back_to_qr():
    """Polynomial columns t^0..t^9 (condition 2.4e6 after unit scaling): the normal equations
    would be off by 1.2e-4 (measured); the QR path keeps lstsq accuracy."""
    t = np.linspace(0.0, 1.0, 40_000)
    a = t[:, None] ** np.arange(10)
    coef = np.linspace(1.0, -1.0, 10)
    b = a @ coef
    got = solve_blocks([Block.make("poly", a)], b)
    ref = np.linalg.lstsq(a, b, rcond=None)[0]
    assert np.max(np.abs(got.coef - ref)) < 1e-7 and got.rms < 1e-12


@pytest.mark.parametrize("model_cls", [StaticPI, GRPI])
def test_zero_weight_rows_are_ignored_by_the_fit(model_cls):
    """Corrupt the second half of the record, weight it 0: the truth comes back exactly."""
    truth = StaticPI(thresholds_v=equal_thresholds(120.0, 10))
    truth.weights_um_per_v, truth.offset_um = WEIGHTS.copy(), 0.3
    drive = Record.from_waveform(biased_sine(10.0, 4, FS))
    x = truth.predict(drive)
    half = drive.n_samples // 2
    x[half:] += 0.5 * np.sin(np.arange(drive.n_samples - half) / 50.0)
    weights = np.r_[np.ones(half), np.zeros(drive.n_samples - half)]
    model = model_cls().fit(drive.with_x(x), row_weights=weights)
    np.testing.assert_allclose(model.weights_um_per_v, WEIGHTS, rtol=1e-6)
    assert model.train_rms_um < 1e-9
    with pytest.raises(ValueError, match="row_weights has 3"):
        model_cls().fit(drive.with_x(x), row_weights=[1.0, 1.0, 1.0])


def test_an_appended_effect_block_is_fitted_jointly_with_the_hysteresis():
    """Static PI + a sensor drift of 0.05 µm/s: the drift column recovers both exactly."""
    truth = StaticPI(thresholds_v=equal_thresholds(120.0, 10))
    truth.weights_um_per_v, truth.offset_um = WEIGHTS.copy(), 0.3
    drive = Record.from_waveform(biased_sine(1.0, 4, FS))
    series = drive.with_x(truth.predict(drive) + 0.05 * drive.t_s)
    model = StaticPI(thresholds_v=truth.thresholds_v)
    blocks = model.design_blocks(series) + [Block.make("drift_um_per_s", series.t_s)]
    sol = solve_blocks(blocks, series.x_um)
    np.testing.assert_allclose(sol.values["weights_um_per_v"], WEIGHTS, rtol=1e-6)
    assert sol.values["drift_um_per_s"][0] == pytest.approx(0.05, rel=1e-6)
    a, lower, upper = model.design_matrix(series)
    assert a.shape == (series.n_samples, 11) and np.all(lower[:10] == 0.0) and np.isinf(lower[10])
    with pytest.raises(ValueError, match="same blocks in the same order"):
        stack_blocks([blocks, blocks[:1]])


def test_two_stage_follows_the_paper_and_joint_is_at_least_as_good(dynamic_data):
    truth, data = dynamic_data
    joint = identify("dynamic_pi", data)
    staged = identify("dynamic_pi", data, method="two_stage")
    static_1hz = StaticPI(thresholds_v=equal_thresholds(120.0, 10)).fit(data[0])
    np.testing.assert_array_equal(staged.weights_um_per_v, static_1hz.weights_um_per_v)  # ω from the 1 Hz loop
    assert joint.train_rms_um <= staged.train_rms_um
    assert joint.train_rms_um < 1e-9
    # the ω bias of stage 1 (rate terms are small but not zero at 1 Hz) limits the two-stage fit
    assert staged.train_rms_um < 0.05 * np.std(np.concatenate([s.x_um for s in data]))
    explicit = fit_dynamic_pi_two_stage(data, static_data=[data[1]])
    assert not np.array_equal(explicit.weights_um_per_v, staged.weights_um_per_v)


def test_pso_minimises_a_quadratic():
    """8-D ill-scaled quadratic; measured ‖x − c‖∞ ≈ 2e-5 after the paper's 100 × 100."""
    c = np.array([0.3, -0.7, 0.1, 0.5, -0.2, 0.9, -0.4, 0.05])
    h = np.linspace(1.0, 10.0, 8)
    res = pso_minimize(lambda x: ((x - c) ** 2 * h).sum(axis=1), np.ones(8), seed=0)
    assert np.max(np.abs(res.x - c)) < 1e-3
    assert res.n_evaluations == 100 * 101 and res.history.size == 100
    assert np.all(np.diff(res.history) <= 0)
    again = pso_minimize(lambda x: ((x - c) ** 2 * h).sum(axis=1), np.ones(8), seed=0)
    np.testing.assert_array_equal(again.x, res.x)  # seeded


@pytest.mark.slow
def test_pso_recovers_alpha_beta_from_noise_free_data(dynamic_data):
    """ω fixed at the truth: PSO finds α1..4, β1..4 to 1e-2 relative (measured ≤ 2.1e-3, seeds 0 and 1)."""
    truth, data = dynamic_data
    rate = stack_blocks(
        [[b for b in truth.blocks(Drive.of(s)) if b.name != "weights_um_per_v" and b.name != "offset_um"] for s in data]
    )
    a = np.hstack([b.columns for b in rate])
    static_part = DynamicPI.from_static(truth)
    target = np.concatenate([s.x_um - static_part.predict(s) for s in data])
    scale = np.linalg.norm(target) / np.linalg.norm(a, axis=0)
    res = pso_minimize(lambda x: np.sqrt(np.mean((target[:, None] - a @ x.T) ** 2, axis=0)), scale, seed=0)
    theta = np.concatenate([truth.alpha_um_per_v2_s, truth.beta_um_per_v2_s2])
    np.testing.assert_allclose(res.x, theta, rtol=1e-2)


@pytest.mark.slow
def test_paper_pso_reaches_the_two_stage_optimum(dynamic_data):
    """Same problem (ω from the 1 Hz loop): PSO's RMS equals the exact stage-2 LS to 1e-4 relative."""
    _, data = dynamic_data
    staged = fit_dynamic_pi_two_stage(data)
    pso, result = fit_dynamic_pi_pso(data, seed=0)
    np.testing.assert_array_equal(pso.weights_um_per_v, staged.weights_um_per_v)
    assert staged.train_rms_um <= pso.train_rms_um * (1 + 1e-12)
    assert pso.train_rms_um < staged.train_rms_um * (1 + 1e-4)
    assert result.cost == pso.train_rms_um


def test_fit_metrics_by_hand():
    m = fit_metrics([1.0, 2.0, 3.0], [1.0, 2.0, 4.0])
    assert m["rms_um"] == pytest.approx(np.sqrt(1 / 3))
    assert m["max_abs_um"] == 1.0
    assert m["fit_percent"] == pytest.approx(100 * (1 - 1 / np.sqrt(2)))
    with pytest.raises(ValueError, match="shape"):
        fit_metrics([1.0, 2.0], [1.0])


def test_identify_dispatch_and_errors(dynamic_data):
    _, data = dynamic_data
    model = identify("static_pi", data[:1], n_operators=6)
    assert isinstance(model, StaticPI) and model.n_operators == 6
    rows = evaluate(model, data[:2])
    assert [r["label"] for r in rows] == ["1 Hz", "10 Hz"] and rows[0]["fit_percent"] > 90
    with pytest.raises(ValueError, match="unknown model 'preisach'"):
        identify("preisach", data)
    with pytest.raises(ValueError, match="method 'pso' is not available for 'grpi'"):
        identify("grpi", data, method="pso")
    with pytest.raises(ValueError, match="no data"):
        identify("static_pi", [])


@pytest.mark.slow
def test_benchmark_reports_ls_no_worse_than_pso():
    """The timing ratio is reported, not asserted (timings are benchmarks, not tests)."""
    out = run_identification_benchmark(seed=0, repeats=1)
    assert {"ls_s", "pso_s", "speedup", "ls_rms_um", "pso_rms_um"} <= out.keys()
    assert out["speedup"] == pytest.approx(out["pso_s"] / out["ls_s"])
    assert out["ls_rms_um"] <= out["pso_rms_um"]
    assert out["ls_rms_um"] <= out["truth_rms_um"]  # the truth is a feasible point of the LS problem
    assert out["ls_rms_um"] == pytest.approx(0.005, rel=0.02)  # down to the 5 nm noise
