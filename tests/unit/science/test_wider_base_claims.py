"""Issue 38 §4: where the base cannot draw a stage's loop and its capacity comes first, a physical
claim stands only if it still passes the claim rule against its reference + that capacity, judged in
the same diagnosis (service.science.discovery.wider_base). Stages built without the product's code
(tests/support/disturbed_stages.py and hysteresis_worlds.py), 5 kHz.

Before, clean stages claimed physics here: a Gaussian Preisach plane `rate_dependence` (27 nm² over
the model + operators + asymmetry, one CSV per block, 1 and 3 nm of noise), a Krasnosel'skii–
Pokrovskii stack `rate_dependence` or `sensor_nonlinearity` — 14 of 120 clean diagnoses.
"""

from __future__ import annotations

import pytest

from service.science.discovery.diagnosis import diagnose
from tests.support import disturbed_stages, hysteresis_worlds

FS = 5000.0  # Hz
pytestmark = pytest.mark.filterwarnings("ignore")  # the fits' numerical warnings on these stages


@pytest.mark.parametrize(
    ("world", "form", "wrongly"),
    [("preisach_gauss", "blocks", "rate_dependence"), ("jiles_atherton", "long", "gain_change")],
)
def test_a_clean_stage_the_base_cannot_draw_claims_no_physics_beyond_its_loop_shape(world, form, wrongly):
    """Only the loop's own shape may be named (both loops have an even part: a Preisach plane with a
    correlated density, a saturating Jiles–Atherton stack); it is claimed by a model-free test, not on
    the wider base."""
    d = diagnose(disturbed_stages.records(world, "clean", form, 0.001, 0, FS))
    claimed = {c["effect"] for c in d["candidates"] if c["kind"] == "physical" and c["claimed"]}
    assert claimed <= {"asymmetry", "sensor_nonlinearity"}, claimed
    assert d["answer"]["kind"] == "capacity"  # grow the base first
    row = next(c for c in d["candidates"] if c["effect"] == wrongly)
    assert row["wider_base"]["stands"] is False and "Judged again on the wider base" in row["evidence"]
    assert row["evidence"].endswith("not claimed.")


def test_a_hidden_effect_is_still_claimed_and_named_first_on_such_a_stage():
    """Creep behind a Preisach plane, one CSV per block, 2 nm: named and claimed at the first diagnosis."""
    d = diagnose(hysteresis_worlds.records("preisach_gauss", "blocks", 0.002, hidden="creep", fs=FS))
    physical = [c for c in d["candidates"] if c["kind"] == "physical"]
    assert physical[0]["effect"] == "creep" and physical[0]["claimed"]
    assert physical[0].get("wider_base", {"stands": True})["stands"]
