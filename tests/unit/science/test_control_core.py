"""Control building blocks without a long run: PID anti-windup and derivative filter, the ellipse
reference, and the safety/mode refusals with their reasons (emulated default bench)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drivers.factory import open_bench
from service.science.control import kernels as CK
from service.science.control.loop import PIDGains
from service.science.control.safety import ControlRefused, available_modes
from service.science.control.session import SCANNED_PID, Controller, plan
from service.science.control.trajectory import Ellipse, reference

DT = 1 / 20_000


def _pid(kp=50.0, ki=300.0, kd=0.0, tf=1e-4):
    return np.array([kp, ki, kd, tf, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]), np.zeros(CK.NPS)


def test_pid_integrator_does_not_wind_up_while_clamped_and_recovers_fast():
    p, s = _pid()
    u = 0.0
    for _ in range(4000):  # 0.2 s of +1 µm error with the output stuck at 120 V
        u = CK.pid_step(p, s, 1.0, 115.0, u, 0.0, 120.0, 1e9, DT)
    assert u == 120.0
    naive = 300.0 * 1.0 * 4000 * DT  # 60 V an unprotected integrator would have gathered
    assert s[CK.S_INT] < 0.1 * naive
    for k in range(200):  # noqa: B007 - k is read after the loop: the error reverses: the output must leave the clamp at once
        u = CK.pid_step(p, s, -0.05, 115.0, u, 0.0, 120.0, 1e9, DT)
        if u < 120.0:
            break
    assert k <= 1 and u < 120.0
    # without anti-windup (same law, integral updated unconditionally) it would stay clamped for long
    i_naive = naive
    steps = int(np.ceil((115.0 + i_naive - 2.5 - 120.0) / (300.0 * 0.05 * DT)))
    assert steps > 1000


def test_pid_rate_clamp_and_filtered_derivative():
    p, s = _pid(kp=0.0, ki=0.0, kd=0.06, tf=1e-3)
    d0 = CK.pid_step(p, s, 1.0, 60.0, 60.0, 0.0, 120.0, 1e9, DT) - 60.0  # unit error step
    assert d0 == pytest.approx(0.06 / (1e-3 + DT))  # not kd/dt = 1200 V
    d1 = CK.pid_step(p, s, 1.0, 60.0, 60.0, 0.0, 120.0, 1e9, DT) - 60.0
    assert 0 < d1 < d0  # decays with tf
    assert CK.clamp_command(100.0, 50.0, 0.0, 120.0, 5.0) == 55.0
    assert CK.clamp_command(-10.0, 1.0, 0.0, 120.0, 50.0) == 0.0


def test_ellipse_ranges_inclination_and_ramps():
    for e in (Ellipse((1, 6), (1, 11), 0, 100, 4), Ellipse((1, 5), (1, 9), 20, 100, 4)):
        ref = reference(e, 20_000.0)
        st = ref.x_um[ref.steady]
        assert st[:, 0].min() == pytest.approx(e.y_range_um[0], abs=1e-3)
        assert st[:, 0].max() == pytest.approx(e.y_range_um[1], abs=1e-3)
        assert st[:, 1].max() == pytest.approx(e.z_range_um[1], abs=1e-3)
        assert np.abs(ref.x_um[0]).max() == 0 and np.abs(ref.x_um[-1]).max() < 1e-3
        a, b = e.semi_axes_um()
        assert a >= b
        # the long axis makes inclination_deg with Z: the largest-radius point's angle to Z
        c = st - st.mean(axis=0)
        far = c[np.argmax(np.hypot(c[:, 0], c[:, 1]))]
        angle = np.degrees(np.arctan2(abs(far[0]), abs(far[1])))
        assert angle == pytest.approx(e.inclination_deg, abs=1.0)
    with pytest.raises(ValueError, match="frequency_hz"):
        reference(Ellipse((1, 6), (1, 11), 0, 123.0, 4), 20_000.0)
    with pytest.raises(ValueError, match="inclination_deg"):
        Ellipse((1, 11), (1, 2), 10, 100, 4).semi_axes_um()
    # the refusal says which spans the inclination allows: Z between the Y span and cot 20° = 2.75× it
    with pytest.raises(ValueError, match=r"between the Y span and 2\.75× it \(here 100×\)"):
        Ellipse((1, 6), (1, 501), 20, 100, 4).semi_axes_um()
    a, b = Ellipse((1, 6), (1, 1 + 2.7 * 5), 20, 100, 4).semi_axes_um()  # just inside the bound: an ellipse
    assert a >= b > 0


@pytest.fixture(scope="module")
def bench():
    b = open_bench("default", seed=3)
    yield b
    b.close()


class _Linear:
    """A stand-in feedforward model (x = gain · V) for the voltage check: the contract's members
    that control uses (service.science.models.contract)."""

    judges_stroke = False

    def __init__(self, um_per_v):
        self.k = um_per_v

    def inverse(self, x_ref_um, *, sample_rate_hz=None, u_limits_v=None):
        return np.asarray(x_ref_um) / self.k

    def predict(self, drive, sample_rate_hz=None):
        return self.k * np.asarray(drive)

    def stack_demand_um(self, x_ref_um, sample_rate_hz=None):
        return np.asarray(x_ref_um, dtype=float)


def test_safety_refusals_say_why(bench):
    ctl = Controller(pid=SCANNED_PID)
    with pytest.raises(ControlRefused, match="150 Vpp at 400 Hz needs 339 mA; the amplifier's limit is 200 mA") as exc:
        plan(bench, Ellipse((1, 6), (1, 11), 0, 400.0, 4), ctl, "point_by_point")
    assert exc.value.field == "frequency_hz"
    with pytest.raises(ControlRefused, match="first resonance") as exc:
        plan(bench, Ellipse((1, 6), (1, 11), 0, 200.0, 4), ctl, "point_by_point")
    with pytest.raises(
        ControlRefused, match=r"needs .*V by the feedforward model; the actuator limit is 0–150 V"
    ) as exc:
        plan(
            bench,
            Ellipse((1, 6), (1, 19), 0, 100.0, 4),
            Controller(feedforward={"y": _Linear(0.09), "z": _Linear(0.09)}),
            "point_by_point",
        )
    assert exc.value.field == "z_range_um"
    with pytest.raises(ControlRefused, match="the gauge reads") as exc:
        plan(bench, Ellipse((2, 12), (1, 14), 0, 100.0, 4), ctl, "point_by_point")
    assert exc.value.field == "y_range_um"
    ref, u_ff = plan(bench, Ellipse((1, 6), (1, 11), 0, 100.0, 4), ctl, "point_by_point")
    assert u_ff is None and ref.x_um.shape == (10 * 200, 2)


def test_modes_follow_the_daq_capabilities(bench):
    ellipse = Ellipse((1, 6), (1, 11), 0, 100.0, 4)
    assert available_modes(bench) == {"point_by_point": None, "buffered": None}
    with pytest.raises(ControlRefused, match="per-sample PID needs point-by-point") as exc:
        plan(bench, ellipse, Controller(pid={"y": PIDGains(1, 1), "z": PIDGains(1, 1)}), "buffered")
    assert exc.value.field == "controller.pid"
    plan(bench, ellipse, Controller(ilc=True), "buffered")
    daq = bench.parts.daq
    original = daq.capabilities
    daq.capabilities = dataclasses.replace(
        original, point_by_point=False, point_by_point_reason="USB X Series: buffered streaming only"
    )
    try:
        assert daq.stepping_hook() is None
        with pytest.raises(ControlRefused, match="USB X Series: buffered streaming only") as exc:
            plan(bench, ellipse, Controller(pid=SCANNED_PID), "point_by_point")
        assert exc.value.field == "mode"
    finally:
        daq.capabilities = original


def learning_matrices(ilc) -> np.ndarray:
    """(2, period, period) dense reference of one ILC step: Δu = irfft(Q·γ/Ĝ·rfft(e)) per axis."""
    eye = np.eye(ilc.period)
    E = np.fft.rfft(eye, axis=0)[: ilc.harmonics + 1]
    out = np.empty((2, ilc.period, ilc.period))
    for a in range(2):
        dU = np.zeros((ilc.period // 2 + 1, ilc.period), dtype=complex)
        dU[: ilc.harmonics + 1] = ilc.gain * E / ilc.g[a][:, None]
        out[a] = np.fft.irfft(dU, n=ilc.period, axis=0)
    return out


def test_compiled_ilc_step_equals_the_learning_matrices_and_projects_into_the_limits():
    from service.science.control.ilc import HarmonicILC

    rng = np.random.default_rng(0)
    g = (rng.standard_normal((2, 21)) + 1j * rng.standard_normal((2, 21))) * 0.05
    g[:, 0] = np.abs(g[:, 1])
    e = rng.standard_normal((200, 2)) * 0.01
    ilc = HarmonicILC(g, 200)
    dense = np.matmul(learning_matrices(ilc), e.T[:, :, None])[:, :, 0].T
    assert np.allclose(ilc.update(e), dense, atol=1e-12)  # harmonic DFT/irfft = dense L·e
    ilc = HarmonicILC(g, 200, gain=1.0)
    base = np.full((200, 2), 119.0)
    u = ilc.update(e * 100, base_v=base, limits_v=(np.zeros(2), np.full(2, 120.0)))
    assert np.all(base + u <= 120.0 + 1e-12) and np.all(base + u >= -1e-12) and np.any(u == 1.0)


def test_a_model_fitted_on_other_turning_points_is_said_to_extrapolate_the_trajectorys_loop():
    """validation.trained_loops_v reads a record's trained loops (its training cycles, own axis only);
    feedforward.untrained_turning_points: a 0-120 V loop does not cover a 13-85 V trajectory (its
    turning points are 13 and 35 V away, more than a quarter of the 72 V swing); a 8-90 V loop does, and
    so does a model trained on both; the message names the axis, the spans and the span sweeps."""
    from service.science.control.feedforward import untrained_turning_points
    from service.science.data.record import Record
    from service.science.fitting.validation import trained_loops_v

    fs, f = 2000.0, 10.0
    t = np.arange(int(fs * 5 / f)) / fs

    def loop(lo, hi):
        u = lo + (hi - lo) * 0.5 * (1 - np.cos(2 * np.pi * f * t))
        other = np.concatenate([np.zeros(u.size), 200.0 * np.ones(u.size)])  # Z's block: not Y's loop
        blocks = [
            {"index": 0, "start": 0, "stop": u.size, "kind": "sine", "cycles": 5, "frequency_hz": f, "axes": ["y"]},
            {
                "index": 1,
                "start": u.size,
                "stop": 2 * u.size,
                "kind": "sine",
                "cycles": 5,
                "frequency_hz": f,
                "axes": ["z"],
            },
        ]
        u_y = np.concatenate([u, np.full(u.size, lo)])
        return Record(u_y, 0.06 * u_y, fs, blocks=blocks, axis="y", u_other_v=other, hold_out=True)

    full, span = trained_loops_v([loop(0.0, 120.0)]), trained_loops_v([loop(8.0, 90.0)])
    assert np.allclose(full, [[0.0, 120.0]], atol=0.1) and np.allclose(span, [[8.0, 90.0]], atol=0.1)
    why = untrained_turning_points(full, "y", (13.0, 85.0))
    assert why is not None and why.startswith("Y:") and "13–85 V" in why and "0–120 V" in why
    assert "35 V" in why and "/api/trajectories/span-sweeps" in why
    assert untrained_turning_points(span, "y", (13.0, 85.0)) is None
    assert untrained_turning_points(full + span, "y", (13.0, 85.0)) is None
    assert untrained_turning_points(full, "y", (5.0, 118.0)) is None  # the full loop's own span


def test_a_model_whose_datasets_cannot_be_read_is_not_judged_and_the_run_is_told(store):
    """usecases.track.extrapolated_loops never stops a run: a model stored without its trained loops,
    whose dataset is gone, gets a warning that its training span was not checked."""
    from types import SimpleNamespace

    from service.usecases.track import extrapolated_loops

    row = store.add_model(
        {
            "axis": "y",
            "kind": "static_pi",
            "effects": ["hysteresis"],
            "datasets": ["ds_gone"],
            "parameters": {"model": "static_pi"},
            "metrics": {},
        }
    )
    said = extrapolated_loops(
        store, SimpleNamespace(axes=("y", "z")), {"feedforward_model_y": row["id"]}, np.full((10, 2), 50.0)
    )
    assert len(said) == 1 and said[0].startswith("Y: the feedforward model's datasets could not be read")
    assert "ds_gone" in said[0] and "not checked" in said[0]
