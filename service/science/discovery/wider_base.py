"""Physical claims judged again on the wider base, within the diagnosis that made them (issue 38 §4).

Where the base cannot draw the stage's loop (a PI on a Preisach, Krasnosel'skii–Pokrovskii or
Jiles–Atherton stack), the capacity that draws it comes first (base_capacity.py), and the physical
candidates were claimed against a reference that leaves the base's misfit, 10–90× the noise: part of
that misfit is drawn by any candidate's columns. A clean Preisach stage had rate dependence claimed
(27 nm² over the model + operators + asymmetry) although the capacity alone reached the noise floor
(62.9 → 1.01 nm at 1 nm of noise), and 14 of 120 clean-stage diagnoses claimed physics so. The next
step of the loop judged them again on the wider base; the diagnosis's own table did not.

Here each claimed physical candidate is tested again by the same claim rule (the diagnosis's alpha,
NOISE_MULTIPLE·σ²) against its reference + that capacity: the claim stands only where it still lowers
the held-out error there, and its evidence says which way the test went. A disturbance seen at rest
is not judged on a model and is left as it is; neither is the loop-shape pair (a stack's asymmetry, a
gauge's bow), whose claim is a model-free symmetry test (no point-symmetric loop has an even part):
the wider base's Preisach plane draws an even part too, so judged there a real asymmetry is taken
for the base's shape (the emulator's hidden asymmetry and gauge bow went unnamed on four benches).
"""

from __future__ import annotations

from service.science.discovery.candidate_rows import Judged, effect_test
from service.science.discovery.decision import claimed
from service.science.discovery.loop_shape import LOOP_SHAPE
from service.science.effects import EFFECTS


def judge_on_wider_base(candidates: list[dict], judged: Judged, capacity: str, alpha: float) -> list[str]:
    """Test every claimed physical row of ``candidates`` again against its reference + ``capacity`` (the
    capacity the loop adds before the physics); a row that no longer passes the claim rule is no longer
    claimed. Each row's evidence gets the test's figures. Returns the effects no longer claimed."""
    dropped = []
    for c in candidates:
        name = c["effect"]
        if not c["claimed"] or c["kind"] != "physical" or EFFECTS[name].seen_at_rest or name in LOOP_SHAPE:
            continue
        tried = effect_test(name, tuple(c["reference"]) + (capacity,), judged)
        stands = claimed(tried.test, judged.noise, alpha)
        words = f" Judged again on the wider base ({capacity} draws the loop this model cannot): {tried.words}: "
        if stands:
            words += "it still lowers the held-out error there, so the claim stands."
        else:
            words += (
                f"it does not pass the claim rule there: what it fitted over the narrower reference was the "
                f"loop shape {capacity} draws, not claimed."
            )
            c.update(claimed=False, high=False, significant=False)
            dropped.append(name)
        c["evidence"] = c["evidence"] + words
        c["wider_base"] = {
            "capacity": capacity,
            "p": tried.test["p"],
            "stands": stands,
            "reference_rms_um": tried.v_ref,
        }
    return dropped
