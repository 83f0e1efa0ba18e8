"""The order of a diagnosis's candidates: claimed physics first, the other physics, capacity last.

Every claimed physical candidate gets one size, comparable across candidates (µm²): the held-out
mean square it removes over the reference its claim was tested against, on the plain residuals of
this diagnosis's fits, with each block's level anchored at its training mean. The reference is the
one that rules out the other explanation of the candidate's signature: the model + the flexible base
(loop shape) for physics fitted against it; the model itself for the loop-shape pair (asymmetry, the
gauge's bow), whose claim a model-free symmetry test made (no point-symmetric family has an even
part, so the base's non-symmetric operators draw the same loop, not another explanation of it:
added to them, the stack's asymmetry removes 1–60 nm² on the default and paper_measured benches,
added to the model 2100–6200 nm²). A disturbance seen at rest is sized by its lines' mean square.

Why one size: the claims' own figures differ in what they hold fixed. Adding each alone to the model
(the ranking before) credits a candidate with flexible columns for the loop shape the base would have
drawn (the dynamics bench's Y at 10/50 Hz: rate dependence alone 12.96 → 5.83 nm, the mode alone →
7.14 nm, over the base 175.7 nm² for the mode and 174.4 nm² for rate dependence); a time effect's
test is taken beyond a gain change fitted on the training rows and extrapolated, which inflates it
(bw_temperature Z: drift 2163 nm² beyond a gain change, 408 nm² as it is, temperature 610 nm²); and
the claim's p takes whichever anchoring is the larger. The training-mean anchor keeps a slow effect's
level, most of which the last-cycle anchor removes.
"""

from __future__ import annotations

from service.science.data.units import fmt_nm2
from service.science.discovery.decision import held_out_improvement
from service.science.discovery.verdict import raised


def claim_size(records, res_reference, res_with) -> tuple[float, float]:
    """A claim's size (µm²): the held-out mean square removed from the residuals of its reference
    (``res_reference``) by those of the reference with it (``res_with``), the claim's own fits, each
    block's level anchored at its training mean; and the whole it is a part of, the reference's own
    held-out mean square at that anchoring (µm²). The claimed row's score is of the size, so the rank
    and the row say one number."""
    test = held_out_improvement(records, res_reference, res_with)
    return float(test["gain_trend_mse_um2"]), float(test["reference_trend_mse_um2"])


def size_words(size_um2: float, reference: tuple, whole_um2: float | None = None) -> str:
    """The claim's size in words, with what it was measured against and, given ``whole_um2``, the
    reference's own held-out mean square at the same anchoring (µm²), the whole the size is a part of
    (its held-out RMS, printed beside it, is of levels not anchored: a walk read 10300 nm² "removed"
    from a reference of 92.2 nm, 8500 nm²)."""
    against = "the model" if not reference else "the model + " + " + ".join(reference)
    anchored = "(each block's level anchored at its training mean)"
    if raised(size_um2):
        return f"its size, the rank's figure: held-out mean square raised by {fmt_nm2(-size_um2)} over {against} {anchored}"
    if whole_um2:
        return (
            f"its size, the rank's figure: {fmt_nm2(size_um2)} of the {fmt_nm2(whole_um2)} held-out mean square of "
            f"{against}, removed {anchored}"
        )
    return f"its size, the rank's figure: {fmt_nm2(size_um2)} of held-out mean square removed over {against} {anchored}"


def rank_key(c: dict) -> tuple:
    """Claimed physics first, by their size (``claim_size_um2``: one figure for every claim), then the
    other physical candidates, capacity last, each by score (one denominator for every score, so the
    order is the held-out gain's)."""
    claimed_physics = c["claimed"] and c["kind"] != "capacity"
    first = -c.get("claim_size_um2", 0.0) if claimed_physics else -c["score"]
    return (c["kind"] == "capacity", not c["claimed"], first, -c["score"], -c["gain_mse_um2"])


def size_claims(candidates: list[dict], at_rest=frozenset()) -> None:
    """Give every claimed physical row its ``claim_size_um2`` (µm²), the figure its score is of
    (``gain_mse_um2``: ``claim_size`` on its test's fits, or for the effects in ``at_rest``, a disturbance
    the rests showed and already out of the record, the lines' mean square), and say it in its evidence."""
    for c in candidates:
        if not c["claimed"] or c["kind"] == "capacity":
            continue
        reference = tuple(c["reference"])
        size = c["claim_size_um2"] = c["gain_mse_um2"]
        words = (
            f"its size, the rank's figure: {fmt_nm2(size)} of mean square in the lines seen at rest"
            if c["effect"] in at_rest
            else size_words(size, reference, c.get("reference_mse_um2"))
        )
        c["evidence"] = c["evidence"].rstrip(".") + f"; {words}."
