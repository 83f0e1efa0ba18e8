"""When discovery's base grows before the physics: the capacity step that comes first (issue 37).

The loop adds physics first and capacity once physics is complete, so that a physical effect is
never hidden by a freer loop shape. But when the base cannot draw the stage's loop at all (a PI on
a Bouc–Wen or Preisach stack: Masing's rule), its misfit is 10–20× the noise and the diagnosis
reads it as a loop-shape effect (an asymmetric loop, a gauge's bow) that is then claimed, or as an
ambiguity between the two that stops the loop. A rate-independent capacity candidate that the claim
rule passes against the model itself and that leaves less than 1/SEPARATED_EXCESS_RATIO of the
best physical claim's excess over the noise floor (held-out RMS² − σ²) says the residual is the base's
loop shape: the base grows first, reported as capacity, never as physics, and the physical
candidates are judged again on it at the next step.
"""

from __future__ import annotations

from service.science.discovery.ambiguity import SEPARATED_EXCESS_RATIO, remaining_excess
from service.science.effects import EFFECTS

#: a later grid of the base (service.science.effects.hysterons: ``Effect.alternative_to`` an effect
#: registered before it) is tried only where the earlier grids leave the held-out RMS above this many
#: times the noise floor (the clean-stage figure issue 37 asks of the base: the smallest grid that
#: reaches it is kept), and it comes before the physics only where it reaches it itself: a rate-
#: independent base that draws the whole record to the noise leaves nothing for physics to explain,
#: while one that only draws more of it (two slow Duhem hysterons drew the default bench's
#: asymmetric loop and part of its creep) must not take the physics' place
GOOD_ENOUGH_TO_NOISE = 1.5


def later_grid(name: str) -> bool:
    """Whether ``name`` is an alternative (``Effect.alternative_to``) to an effect registered before it."""
    names, alternatives = list(EFFECTS), set(EFFECTS[name].alternative_to)
    return any(n in alternatives for n in names[: names.index(name)])


def capacity_before_physics(d: dict) -> dict | None:
    """The capacity candidate of diagnosis ``d`` the loop adds before its top claimed physical one
    (see the module docstring), or None."""
    if d["verdict"] != "missing_effect":
        return None
    noise = d["noise_floor_um"] or 0.0
    top = next(c for c in d["candidates"] if c["kind"] == "physical" and c["claimed"])
    capacity = [
        c
        for c in d["candidates"]
        if c["kind"] == "capacity"
        and c.get("claimed")
        and (
            not later_grid(c["effect"])
            or not EFFECTS[c["effect"]].adds_memory
            or c["expected_rms_um"] <= GOOD_ENOUGH_TO_NOISE * noise
        )
    ]
    if not capacity:
        return None
    best = parsimonious(capacity, noise)
    if remaining_excess(top, noise) >= SEPARATED_EXCESS_RATIO * remaining_excess(best, noise):
        return best
    return None


def parsimonious(capacity: list[dict], noise: float) -> dict:
    """The capacity candidate to add: the lowest held-out RMS, except that a grid of the base with more
    parameters than an alternative to it (``Effect.alternative_to``) is taken only where it leaves less
    than 1/SEPARATED_EXCESS_RATIO of that alternative's excess over the noise floor. A freer grid that
    is only a little better held out is not worth its parameters: on a Jiles–Atherton record the fine
    grid's 13 % lower RMS came with a gain change read into the virgin loading curve."""
    best = min(capacity, key=lambda c: c["expected_rms_um"])
    size = {c["effect"]: c.get("added_parameters", 0) for c in capacity}  # a row written before the field: no order
    for c in sorted(capacity, key=lambda c: size[c["effect"]]):
        smaller = c["effect"] in EFFECTS[best["effect"]].alternative_to and size[c["effect"]] < size[best["effect"]]
        if smaller and remaining_excess(c, noise) < SEPARATED_EXCESS_RATIO * remaining_excess(best, noise):
            return c
    return best
