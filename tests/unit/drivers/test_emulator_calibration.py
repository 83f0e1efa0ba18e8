"""Calibration of the default bench against the paper, and strength of the hidden-effect variants.

The static PI here (10 play operators, thresholds 0, 6, …, 54 V, NNLS weights + free offset) is
the paper's model; the emulator itself is a Preisach model and never uses play operators.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from service.reports.calibration import PAPER, THRESHOLDS_V, VARIANTS, measure_calibration, play_outputs, sweep_pi_rms

#: Emulator sweeps of every bench; one worker runs the file: its calibration and base-bench sweeps are
#: module fixtures.
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("emulator_calibration")]


def play_reference(u: np.ndarray, r: float, y0: float = 0.0) -> np.ndarray:
    """Numpy reference: y_k = max(u_k − r, min(u_k + r, y_{k−1}))."""
    y = np.empty_like(u)
    prev = y0
    for k, uk in enumerate(u):
        prev = max(uk - r, min(uk + r, prev))
        y[k] = prev
    return y


def test_compiled_play_matches_numpy_reference():
    rng = np.random.default_rng(0)
    u = np.cumsum(rng.standard_normal(3000)) + 60 * np.sin(np.linspace(0, 20, 3000))
    p = play_outputs(u, THRESHOLDS_V)
    for j, r in enumerate(THRESHOLDS_V):
        assert np.array_equal(p[:, j], play_reference(u, r))
    assert play_reference(np.array([0.0, 10.0, 4.0, 20.0]), 3.0).tolist() == [0.0, 7.0, 7.0, 17.0]


@pytest.fixture(scope="module")
def calibration():
    return measure_calibration("default", seed=0)


@pytest.mark.parametrize("axis", ["y", "z"])
def test_default_bench_matches_the_paper(calibration, axis):
    c, p = calibration["axes"][axis], PAPER[axis]
    assert c["stroke_um"] == pytest.approx(p["stroke_um"], rel=0.10)
    assert 10.0 <= c["loop_width_pct"] <= 15.0
    assert p["pi_rms_1hz_um"] / 2 <= c["pi_rms_1hz_um"] <= p["pi_rms_1hz_um"] * 2
    assert c["pi_rms_100hz_um"] > c["pi_rms_1hz_um"]  # static PI error grows with rate
    loops = c["per_frequency"]
    assert loops[100.0]["loop_width_pct"] > loops[1.0]["loop_width_pct"]  # loops widen with frequency
    assert c["pi_weight_sum_um_per_v"] * 120 == pytest.approx(p["stroke_um"], rel=0.15)


@pytest.fixture(scope="module")
def base_rms():
    return sweep_pi_rms("base")["both"]


def test_base_is_close_to_the_noise_floor(base_rms):
    assert base_rms < 0.015  # 3 nm gauge noise; the rest is the Preisach/PI mismatch


@pytest.mark.parametrize("variant", VARIANTS)
def test_each_variant_leaves_a_clearly_larger_pi_error_than_base(variant, base_rms):
    assert sweep_pi_rms(variant)["both"] >= 2.0 * base_rms


def test_emulator_never_uses_the_service_or_play_operators():
    root = Path(__file__).resolve().parents[3] / "drivers" / "emulated"
    for path in root.glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                assert not (node.module or "").startswith("service"), path
            elif isinstance(node, ast.Import):
                assert not any(a.name.startswith("service") for a in node.names), path
        names = {n.name for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
        names |= {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
        names |= {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
        assert not [x for x in names if "play" in x.lower() or "prandtl" in x.lower()], path
