"""A feedforward whose per-sample inverse misses a periodic reference is solved period by period
(service.science.control.periodic_inverse), and refused only when that misses too."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.factory import open_bench
from service.science.control.feedforward import INVERSE_TOLERANCE_SHARE, feedforward_v, identify, inverse_miss_um
from service.science.control.safety import ControlRefused
from service.science.control.session import converged_drive
from service.science.control.trajectory import Ellipse, reference

FS = 20_000.0


@pytest.fixture(scope="module")
def case1_reference():
    return reference(Ellipse((1.0, 6.0), (1.0, 11.0), 0.0, 100.0, 4), FS)


def test_the_paper_dynamic_pi_follows_the_ellipse_when_solved_period_by_period(case1_reference):
    """Measured on the default bench, Z: the per-sample inverse misses by 2.24 µm RMS (22 % of the
    10 µm range), the periodic drive by 0.33 µm (3.3 %), within the 5 % the plan accepts."""
    ref = case1_reference
    model = identify(open_bench("default", seed=1), "z", "dynamic_pi")
    x_ref = ref.x_um[:, 1]
    per_sample = feedforward_v(model, x_ref, FS)
    span = np.ptp(x_ref[ref.steady])
    assert inverse_miss_um(model, per_sample, x_ref, FS, ref.steady) > INVERSE_TOLERANCE_SHARE * span
    drive = converged_drive(model, "z", 1, per_sample, ref, 100.0)
    miss = inverse_miss_um(model, drive, x_ref, FS, ref.steady)
    assert miss < INVERSE_TOLERANCE_SHARE * span
    # the ramps keep the per-sample inverse, so the drive starts from rest as the reference does
    assert np.allclose(drive[: ref.period], per_sample[: ref.period])
    assert np.all(np.isfinite(drive))


class SaturatingStage:
    """A stage whose output stops at 2 µm, whatever the drive (0.05 µm/V below that)."""

    def predict(self, drive, sample_rate_hz=None):
        return np.clip(0.05 * np.asarray(drive, dtype=float), 0.0, 2.0)


def test_a_reference_no_drive_reaches_is_refused_naming_the_model(case1_reference):
    ref = case1_reference
    x_ref = ref.x_um[:, 0]  # 1…6 µm: beyond the 2 µm the stage reaches
    with pytest.raises(ControlRefused) as refused:
        converged_drive(SaturatingStage(), "y", 0, x_ref / 0.05, ref, 100.0)
    assert refused.value.field == "controller.feedforward_model_y"
    assert "solved period by period" in refused.value.reason and " nm RMS" in refused.value.reason
