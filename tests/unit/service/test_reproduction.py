"""The paper's models on the emulated bench: dynamic PI beats static PI where the physics is rate dependent."""

from __future__ import annotations

import re

import numpy as np
import pytest

from service.reports.calibration import FREQUENCIES_HZ
from service.reports.calibration_fit import target_checks
from service.reports.reproduction import MODEL_COLUMNS, PAPER_TABLE6_UM, render_markdown, reproduce, sweep_series
from service.science.models import DynamicPI, StaticPI


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


def _table_figures(markdown: str) -> dict:
    """The figures of the first Markdown table in ``markdown``: {(axis, frequency Hz): {column
    heading: the numbers in that cell}}; the formatting (widths, separators, digits) is not read."""
    lines = [line for line in markdown.splitlines() if line.startswith("|")]
    heading = [cell.strip() for cell in lines[0].strip("|").split("|")]
    figures = {}
    for line in lines[2:]:
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        key = (cells[0].lower(), float(re.search(NUMBER, cells[1]).group()))
        figures[key] = {h: tuple(float(x) for x in re.findall(NUMBER, c)) for h, c in zip(heading[2:], cells[2:])}
    return figures


NUMBER = r"-?\d+(?:\.\d+)?"
#: Each fitted model and the words of its column's heading.
HEADINGS = {
    "dynamic_joint": "exact LS",
    "dynamic_two_stage": "two-stage",
    "dynamic_pso": "PSO",
    "grpi": "GRPI",
    "static": "static PI",
}


def test_reproduction_table_has_every_model_and_the_papers_figures():
    """Each model's RMS sits in its own column at its axis and frequency (4 decimals, as stated in
    the table), and the paper's Table 6 figures beside them where the paper has them."""

    def figure(axis, model, f_hz):  # a different figure in every cell
        return round(0.01 * (1 + MODEL_COLUMNS.index(model)) + f_hz / 10_000 + (0.5 if axis == "z" else 0.0), 4)

    result = {
        axis: {
            "rms_um": {m: {f"{f:g} Hz": figure(axis, m, f) for f in FREQUENCIES_HZ} for m in MODEL_COLUMNS},
            "fit_s": {"static": 0.01},
        }
        for axis in ("y", "z")
    }
    figures = _table_figures(render_markdown(result))
    assert set(figures) == {(axis, f) for axis in ("y", "z") for f in FREQUENCIES_HZ}
    for (axis, f_hz), row in figures.items():
        for model, words in HEADINGS.items():
            [column] = [h for h in row if words in h and not h.startswith("paper")]
            assert row[column] == pytest.approx((figure(axis, model, f_hz),), abs=5e-5), (axis, f_hz, model)
        [paper] = [h for h in row if h.startswith("paper")]
        expected = PAPER_TABLE6_UM[axis].get(f_hz, ())
        assert row[paper] == pytest.approx(expected, abs=5e-5), (axis, f_hz)


#: Table 6 targets the default bench does not meet, and why (docs/calibration.md, "Residual disagreements").
#: Filled from the calibrated bench's reproduction run; the test asserts this set exactly, so a target
#: that becomes met (or one that is lost) shows here.
FLEXURE_FLOOR = (
    "the first mode (FEM 482.6 / 290.7 Hz) passes the 100 Hz fundamental with |H − 1| ≥ r²/(1 − r²) "
    "at any damping, plus one sample of AO→AI latency; no PI-family model has structural dynamics"
)
Y_NOT_REFITTED = (
    "Y keeps its former values: the Y set the fit found (dynamic PI 1.31×, 25.5 % reduction at 10 Hz) makes "
    "the default-bench discovery test add rate_dependence first and never claim dynamics"
)
UNMET_TARGETS: dict[str, str] = {
    **{
        f"{axis} 100 Hz {model} within ±35 %": FLEXURE_FLOOR
        for axis in ("Y", "Z")
        for model in ("dynamic_joint", "grpi", "static")
    },
    "Y 10 Hz dynamic_joint within ±35 %": Y_NOT_REFITTED,
    "Y 10 Hz reduction within 15 points": Y_NOT_REFITTED,
}


@pytest.fixture(scope="module")
def default_reproduction():
    """One reproduction run of the default bench (seed 0, as docs/reproduction.md), PSO left out."""
    return reproduce("default", seed=0, with_pso=False)


@pytest.mark.slow
@pytest.mark.xdist_group("reproduction")  # both axes read one reproduction run: one worker builds it
@pytest.mark.parametrize("axis", ["y", "z"])
def test_default_bench_meets_the_papers_table6_targets(default_reproduction, axis):
    """Issue 18's targets, read from the reproduction run's figures: each Table 6 cell within ±35 % of
    the paper's, the paper's ordering (dynamic < GRPI ≤ static where the paper has it), the dynamic
    PI's 10 Hz reduction of the static PI's error within 15 points of the paper's, and the 1 Hz stroke
    within 3 %. Every target is met except those in UNMET_TARGETS, which stay unmet."""
    result = default_reproduction[axis]
    stroke = measure_calibration_stroke(axis)
    checks = target_checks(axis, result["rms_um"], stroke)
    missed = {name: figures for name, met, figures in checks if not met}
    expected = {name for name in UNMET_TARGETS if name.startswith(axis.upper() + " ")}
    assert set(missed) == expected, missed
    assert len(checks) >= 10


def measure_calibration_stroke(axis: str) -> float:
    """The 1 Hz stroke (last cycle, µm) of the default bench, as docs/calibration.md measures it."""
    from service.reports.calibration import last_cycle, run_loops

    _, x = run_loops("default", 0, (1.0,), axes=(axis,))[axis][1.0]
    return float(np.ptp(last_cycle(x, x, 1.0)[1]))
