"""Feedforward from a discovery composite model (CompositeModel.inverse): its inverse is exact
on the model itself, any effect discovery may add (the capacity candidate included) inverts, it beats the paper's static-PI feedforward on case 2, and a range beyond the
stroke is refused with the reason (or run clamped, with the reason as a warning)."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.factory import open_bench
from service.science.control.feedforward import identify, identify_composite, identify_composite_for
from service.science.control.safety import ControlRefused
from service.science.control.session import SCANNED_PID, Controller, plan, track
from service.science.control.trajectory import Ellipse, reference

CASE1 = Ellipse((1, 6), (1, 11), 0.0, 100.0, 30)
#: beyond the stroke of the stacks' 0–150 V rating (case 1 is within it: ≈124 V on Z)
BEYOND = Ellipse((1, 6), (1, 14), 0.0, 100.0, 30)
CASE2 = Ellipse((1, 5), (1, 9), 20.0, 100.0, 30)
FS = 20_000.0

#: One worker runs the file: the composite feedforward models are a module fixture.
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("control_composite")]


@pytest.fixture(scope="module")
def bench():
    b = open_bench("default", seed=5)
    yield b
    b.close()


@pytest.fixture(scope="module")
def composite(bench):
    return identify_composite_for(bench, CASE2)


def test_composite_inverse_is_exact_on_the_model(composite):
    ref = reference(CASE2, FS)
    steady = ref.steady
    for i, axis in enumerate("yz"):
        u = composite[axis].inverse(ref.x_um[:, i], sample_rate_hz=FS)
        x = composite[axis].predict(u, sample_rate_hz=FS)
        assert np.max(np.abs(x[steady] - ref.x_um[steady, i])) < 0.005  # µm
        assert "dynamics" in composite[axis].effects and composite[axis].judges_stroke


#: what each effect's model may miss its own case-2 reference by (share of the range, RMS): the damped
#: iteration ends at 0.00-0.25 % for every effect but rate dependence (the bench's state, which the
#: module's earlier tests leave, moves it within that), whose operator-rate terms stall it at 4-6 %; the
#: harmonic Gauss-Newton then takes that below 1 %. Before both: operators 6-15 %, rate dependence
#: 6.6-7.9 %, beyond the 5 % a plan accepts.
INVERSE_MISS_SHARE = {"rate_dependence": 0.015}
INVERSE_MISS_SHARE_OTHERS = 0.01


@pytest.mark.parametrize(
    "effect",
    ["asymmetry", "creep", "rate_dependence", "cross_coupling", "drift", "delay", "sensor_nonlinearity", "operators"],
)
def test_any_discovered_composite_inverts(bench, effect):
    """Issue 19 §4: hysteresis + ``effect`` + dynamics, fitted on a sweep of each axis, is a
    feedforward the plan accepts; its own prediction of its inverse follows the reference. Before the
    damped iteration the capacity candidate (operators) missed by 6–15 % and a one-axis sweep's
    cross-coupling fitted Z by Y's echo (37 µm/µm) and missed by 690 %."""
    ref = reference(CASE2, FS)
    steady = ref.steady
    effects = tuple(dict.fromkeys((effect, "dynamics")))
    ff = {ax: identify_composite(bench, ax, effects) for ax in bench.axes}
    for i, axis in enumerate("yz"):
        x_ref = ref.x_um[:, i]
        u = ff[axis].inverse(x_ref, sample_rate_hz=FS)
        miss = np.sqrt(np.mean((ff[axis].predict(u, sample_rate_hz=FS)[steady] - x_ref[steady]) ** 2))
        assert miss < INVERSE_MISS_SHARE.get(effect, INVERSE_MISS_SHARE_OTHERS) * np.ptp(x_ref[steady]), (axis, miss)
    plan(bench, CASE2, Controller(feedforward=ff), "point_by_point")  # accepted: no ControlRefused


def test_composite_feedforward_beats_static_pi_on_case2(bench, composite):
    static = {ax: identify(bench, ax, "static_pi") for ax in bench.axes}
    res = {}
    for name, ff in (("static", static), ("composite", composite)):
        res[name], _, _ = track(bench, CASE2, Controller(feedforward=ff, pid=SCANNED_PID))
        assert res[name]["tripped"] is None
    # FF + tuned PID (row c' of docs/tracking.md): at least 2× lower RMS and max error, and ≤ 3 %
    assert res["composite"]["rms_error_um"] < 0.5 * res["static"]["rms_error_um"]
    assert res["composite"]["relative_error_pct"] < 0.5 * res["static"]["relative_error_pct"]
    assert res["composite"]["relative_error_pct"] <= 3.0


def test_range_beyond_the_stroke_is_refused_with_the_reason(bench):
    ff = {ax: identify_composite(bench, ax, ("delay", "dynamics")) for ax in bench.axes}
    with pytest.raises(
        ControlRefused,
        match=r"Z 1–14 µm at 100 Hz: the top end 14 µm needs .* V by the feedforward model.* the axis "
        r"reaches \d+\.\d\d µm at 150 V",
    ) as exc:
        plan(bench, BEYOND, Controller(feedforward=ff), "point_by_point")
    assert exc.value.field == "z_range_um" and "allow_saturation" in exc.value.reason
    reach = float(exc.value.reason.split("reaches ")[1].split(" µm")[0])
    demand = float(exc.value.reason.split("must deliver ")[1].split(" µm")[0])
    assert 11.0 < reach < demand < 14.0  # the flexure's gain at 100 Hz lowers the demand, not enough
    # a range whose bottom end is below what 0 V reaches names that end, not the stroke
    with pytest.raises(ControlRefused, match=r"Y 0–5 µm at 100 Hz: the bottom end 0 µm needs -\d+\.\d V") as low:
        plan(bench, Ellipse((0, 5), (1, 9), 0.0, 100.0, 30), Controller(feedforward=ff), "point_by_point")
    assert "below the axis's 0 V limit" in low.value.reason and "top end" not in low.value.reason
    for inside in (CASE2, CASE1):  # case 1 needs ≈124 V on Z: inside the 150 V rating (issue 19)
        plan(bench, inside, Controller(feedforward=ff), "point_by_point")
    warnings: list[str] = []
    ref, u_ff = plan(bench, BEYOND, Controller(feedforward=ff, allow_saturation=True), "point_by_point", warnings)
    assert len(warnings) == 1 and warnings[0].startswith("Z 1–14 µm")
    demand_v = float(warnings[0].split(" V by the feedforward model")[0].rsplit("needs ", 1)[1])
    assert demand_v > 150.0 and u_ff.max() <= 150.0  # the demand beyond the limit runs clamped
    # a hysteresis-only model ignores the flexure's gain at 100 Hz: its verdict is a warning, not a refusal
    static = {ax: identify(bench, ax, "static_pi") for ax in bench.axes}
    warnings = []
    plan(bench, BEYOND, Controller(feedforward=static), "point_by_point", warnings)
    assert len(warnings) == 1 and "without flexure dynamics" in warnings[0] and "reaches" in warnings[0]
