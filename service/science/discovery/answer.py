"""The diagnosis's answer in one stored value: what is missing (or why nothing is), the error it
should fall to, and what remains described — the Models page's first screen, the verdict and the
remainder's section all read it, so they cannot tell two stories (a "Missing: asymmetry" beside a
description of a line disturbance, each built on its own). Errors in µm in the fields, nm in the text.
"""

from __future__ import annotations

from service.science.data.units import fmt_nm, plain


def diagnosis_answer(
    claimed_physical: list[dict],
    capacity: list[dict],
    residual_um: float,
    noise_um: float,
    at_floor: bool,
    remainder: dict | None,
    first_capacity: dict | None = None,
    ambiguity: dict | None = None,
) -> dict:
    """``{"missing", "kind", "expected_rms_um", "ambiguous_with", "remains", "remains_share", "text"}``:
    ``missing`` the effect the verdict names (the best claimed physical one), else the capacity that
    lowers the held-out error when physics is complete and the model is not at the floor, else None;
    ``ambiguous_with`` the look-alike the data cannot tell it from (``ambiguity``: the diagnosis's), else
    None; ``remains`` the remainder's leading signature (None when nothing is described), read from
    ``remainder`` itself."""
    top = (remainder or {}).get("signatures") or []
    other = look_alike(claimed_physical[0]["effect"], ambiguity) if claimed_physical else None
    remains = top[0] if top else None
    if first_capacity is not None:  # the base cannot draw the loop: it grows first (base_capacity.py)
        lead, kind = first_capacity, "capacity"
        head = first_capacity_words(first_capacity, claimed_physical[0], residual_um)
    elif claimed_physical:
        lead, kind = claimed_physical[0], "physical"
        head = (
            f"Missing: {lead['effect']}. Adding it should bring the held-out error from {fmt_nm(residual_um, 4)} "
            f"to about {fmt_nm(lead['expected_rms_um'], 4)}."
            if other is None
            else f"Missing: {lead['effect']} or {other}; the data cannot tell them apart. Adding {lead['effect']}, "
            f"the leading claim, should bring the held-out error from {fmt_nm(residual_um, 4)} to about "
            f"{fmt_nm(lead['expected_rms_um'], 4)}, but it is a guess "
            + (
                "until the experiment that separates them is run."
                if not (ambiguity or {}).get("separating_sweep_in_data")
                else "that the sweeps of this bench cannot settle: the one that would separate them is in the data already."
            )
        )
        head += lead_words(claimed_physical)
    elif capacity and not at_floor:
        lead, kind = capacity[0], "capacity"
        head = (
            f"No physical effect in the library is missing. More hysteresis capacity ({lead['effect']}) should "
            f"bring the held-out error from {fmt_nm(residual_um, 4)} to about {fmt_nm(lead['expected_rms_um'], 4)}: "
            "a model-capacity change, not physics."
        )
    else:
        lead, kind = None, None
        head = (
            "Nothing is missing: the model explains the data down to the noise floor."
            if at_floor
            else "No effect in the library is missing, yet the model is not at the noise floor."
        )
    tail = ""
    if remains is not None:
        before = f" (before adding {lead['effect']})" if lead is not None else ""
        tail = (
            f" What remains in this model{before}, described: {remains['text']} "
            f"({plain(100 * remains['share_of_excess'])} % of the unseen residual above the {fmt_nm(noise_um, 4)} noise)."
        )
    return {
        "missing": None if lead is None else lead["effect"],
        "kind": kind,
        "expected_rms_um": None if lead is None else lead["expected_rms_um"],
        "ambiguous_with": other if kind == "physical" else None,
        "remains": None if remains is None else remains["signature"],
        "remains_share": None if remains is None else remains["share_of_excess"],
        "text": head + tail,
    }


def lead_words(claimed_physical: list[dict]) -> str:
    """Why the leading claim leads where another claim, added alone, would leave less ("" otherwise): the
    claims are ranked by what each removes beyond its reference, the base's loop shape included, while
    an effect added alone is also credited with loop shape its columns draw (a walk read "adding
    asymmetry, the leading claim, … to about 93.41 nm" beside rate_dependence's 90.75 nm)."""
    lead = claimed_physical[0]
    lower = [c for c in claimed_physical[1:] if c["expected_rms_um"] < lead["expected_rms_um"]]
    if not lower:
        return ""
    best = min(lower, key=lambda c: c["expected_rms_um"])
    return (
        f" {best['effect']}, added alone, would leave less ({fmt_nm(best['expected_rms_um'], 4)}); the claims rank by "
        f"the held-out mean square each removes beyond its own reference (the size in its evidence), where "
        f"{lead['effect']} removes the most: added alone, an effect is also credited with any loop shape its "
        "columns draw."
    )


def first_capacity_words(capacity: dict, physical: dict, residual_um: float) -> str:
    """The sentence for a diagnosis whose base cannot draw the loop (``capacity`` comes before the
    claimed ``physical`` effect; service.science.discovery.base_capacity): what the next step adds."""
    return (
        f"The base cannot draw this loop: more hysteresis capacity ({capacity['effect']}) first should bring the "
        f"held-out error from {fmt_nm(residual_um, 4)} to about {fmt_nm(capacity['expected_rms_um'], 4)}, a "
        f"model-capacity change, not physics. {physical['effect']} is claimed against the base as it is (to about "
        f"{fmt_nm(physical['expected_rms_um'], 4)}), and its claim stands on the wider base too (the test is in its "
        "evidence)."
    )


def look_alike(effect: str, ambiguity: dict | None) -> str | None:
    """The other effect of ``ambiguity`` (the diagnosis's: two claimed effects the data explain alike)
    when ``effect`` is one of its two, else None."""
    pair = list((ambiguity or {}).get("effects") or [])
    return next((e for e in pair if e != effect), None) if effect in pair else None
