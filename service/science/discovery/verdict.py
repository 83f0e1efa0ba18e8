"""A diagnosis in words: the verdict, the held-out tests' figures, what a score is of, what the
residual figure is over, and which capacity helps. Units: µm in, nm and nm² in the words."""

from __future__ import annotations

import numpy as np

from service.science.data.units import fmt_nm, fmt_nm2

#: with the flexible base, a held-out drop smaller than this many noise floors is "at the noise floor"
CLEAR_DROP_NOISE = 2.0


def test_words(test: dict, noise: float) -> str:
    """A held-out test's figures in words (both anchorings of the blocks' levels; the p is of the larger),
    each drop beside the reference's own held-out mean square at that anchoring, the whole it is a part
    of (a walk read "10300 nm² removed" against a reference whose RMS, 92.2 nm, squares to 8500 nm²: the
    RMS is of levels not anchored)."""
    at = " at the training mean" if test.get("p_anchor") == "training_mean" else ""
    return (
        f"({p_words(test['p'], test['segments'], at)}; "
        f"{removal(test['gain_mse_um2'], test.get('reference_mse_um2'))} of mean square with each block's level "
        f"anchored at its last training cycle, "
        f"{removal(test['gain_trend_mse_um2'], test.get('reference_trend_mse_um2'))} at its training mean; "
        f"against σ² = {fmt_nm2(noise**2)})"
    )


def removal(drop_um2: float, whole_um2: float | None) -> str:
    """A held-out mean-square drop (µm²) as a part of its reference's held-out mean square ``whole_um2``
    at the same anchoring ("removed 10300 nm² of the reference's 12600 nm²"); a negative drop as a rise
    ("added 50 nm² to the reference's 12600 nm²"); without a whole, the amount alone."""
    verb, amount = ("added", fmt_nm2(-drop_um2)) if raised(drop_um2) else ("removed", fmt_nm2(drop_um2))
    if not whole_um2:
        return f"{verb} {amount}"
    return f"{verb} {amount} {'to' if verb == 'added' else 'of'} the reference's {fmt_nm2(whole_um2)}"


def p_words(p: float, segments: int, at: str = "") -> str:
    """A held-out test's p in words: over how many segments, or that there were too few to test on
    ("p = 1 over 0 held-out segments" read as a test that found nothing)."""
    if segments == 0:
        return "no held-out segments to test on (none held out, or none changed beyond a tie): not tested"
    if segments == 1:
        return "one held-out segment: too few to test (a signed-rank test needs two), not tested"
    return f"p = {p:.2g}{at} over {segments} held-out segments"


def score_words(gain_um2: float, excess_um2: float, reference: tuple = (), anchor: str = "last_cycle") -> str:
    """What a candidate's score is of (one denominator for every row): its test's held-out mean-square
    drop (µm²: against its ``reference``, the mean over held-out stretches, every block alike, levels
    anchored at the last training cycle) over this model's held-out mean square above the noise floor
    (µm²: its held-out RMS² − σ², levels not anchored). Not the ratio of the RMS figures printed beside
    it. The two come from different fits and anchorings: where the drop is the larger, the words say
    so and that the score is capped at 1, never a part over a smaller whole. ``anchor``
    "training_mean": a claim that rests on the levels anchored at the block's training mean."""
    against = "the model" + "".join(f" + {name}" for name in reference)
    level = (
        "at its training mean, the anchoring its claim rests on"
        if anchor == "training_mean"
        else "at its last training cycle"
    )
    by = "adding it" if anchor == "training_mean" else "its test"
    how = f"(against {against}, mean over held-out stretches, each block's level anchored {level})"
    whole = f"{fmt_nm2(excess_um2)} of this model's held-out mean square above the noise floor (its held-out RMS² − σ², levels not anchored)"
    if raised(gain_um2):  # a negative drop is no removal: the test's fit did worse on the held-out cycles
        return (
            f"{by} raised the held-out mean square by {fmt_nm2(-gain_um2)} {how}: nothing removed of {whole}, score 0"
        )
    gain = f"{fmt_nm2(gain_um2)} of held-out mean square removed by {by} {how}"
    if score_capped(gain_um2, excess_um2):
        return f"{gain}; more than {whole}, a whole of another fit and anchoring: the score is capped at 1"
    return f"{gain} / {whole}"


def score_capped(gain_um2: float, excess_um2: float) -> bool:
    """Whether a score is capped at 1: its test's drop exceeds this model's excess at the printed digits
    (a whole of another fit and anchoring), so the 1 is a cap, not a share."""
    return fmt_nm2(gain_um2) != fmt_nm2(excess_um2) and gain_um2 > excess_um2


def raised(drop_um2: float) -> bool:
    """Whether a mean-square drop (µm²) is negative at the printed digits: a rise, never printed as a
    negative amount "removed" (−1520000 nm² removed)."""
    return drop_um2 < 0 and fmt_nm2(drop_um2) != fmt_nm2(0.0)


def share_words(removed: float) -> str:
    """What adding an effect did to this model's held-out mean square above the noise floor, ``removed``
    its share (≤ 1; negative: the held-out RMS rose, which no share "of the excess" states)."""
    if round(100 * removed) < 0:
        return "none of the excess above the noise floor removed: the held-out RMS rises"
    return f"{max(100 * removed, 0.0):.0f} % of the excess above the noise floor"  # never "-0 %"


def residual_words(records) -> str:
    """What ``residual_rms_um`` is: the mean of per-block held-out RMS over every block of the records
    (the blocks that leave the axis undriven too), of the diagnosis's fit; the stored model's own
    figure (``metrics.validation_rms_um``) is over the blocks that drive its axis."""
    n_all = sum(len(r.splits) for r in records)
    n_own = sum(len(r.splits_of(own_axis_only=True)) for r in records)
    undriven = f" ({n_own} that drive the axis, {n_all - n_own} that leave it undriven)" if n_all != n_own else ""
    return f"the mean of per-block held-out RMS over {n_all} blocks{undriven}, of the diagnosis's fit"


def worst_repeatable_to_noise(per_block: list[dict]) -> float | None:
    """The largest ratio over blocks of the repeatable part to that block's own noise: "at the noise
    floor" must hold at every frequency, not only on average."""
    ratios = [
        b["repeatable_um"] / b["noise_um"]
        for b in per_block
        if b.get("repeatable_um") is not None and b.get("noise_um") and np.isfinite(b["noise_um"])
    ]
    return max(ratios) if ratios else None


#: capacity is validated, not claimed: a capacity step the claim rule does not pass is taken where it
#: removes at least this share of the model's held-out mean square above the noise floor (a walk's loop
#: added sensor_nonlinearity, as capacity beside hysterons, for 25.8 → 25.7 nm over a 7.06 nm floor:
#: 0.8 % of the excess, a step that changes nothing the user can see)
CAPACITY_MIN_SHARE = 0.1


def helpful_capacity(candidates, residual_rms_um: float | None = None, noise_um: float = 0.0) -> list[dict]:
    """Capacity candidates that lower the held-out RMS: those the claim rule passes, and (given the
    model's ``residual_rms_um`` and noise floor ``noise_um``, µm) any whose held-out mean square is lower
    by CAPACITY_MIN_SHARE of the excess above the floor — capacity is validated, not claimed."""

    def validated(c: dict) -> bool:
        if residual_rms_um is None:
            return False
        excess = max(residual_rms_um**2 - noise_um**2, 0.0)
        return residual_rms_um**2 - c["expected_rms_um"] ** 2 >= max(CAPACITY_MIN_SHARE * excess, 1e-30)

    return [c for c in candidates if c["kind"] == "capacity" and (c.get("claimed") or validated(c))]


#: a claimed effect that removes less than this share of this model's excess on its own is said to
#: need the flexible base beside it (its claim was against that base)
ALONE_GAIN_SHARE = 0.1


def repeated_words(floor: dict, noise: float) -> str:
    """The repeated cycles' figures as a part of their own whole (the residual's RMS over the same
    cycles, training ones included), never of the held-out figure beside it: "12 nm of their 13 nm
    repeats cycle to cycle, against 3 nm of noise"."""
    rep, whole = floor.get("repeatable_rms_um"), floor.get("repeated_cycles_rms_um")
    if rep is None or whole is None:
        return f"no cycle repeats, so no repeatable part is measured ({fmt_nm(noise)} of noise)"
    return (
        f"in the repeated cycles (training and held-out), {fmt_nm(rep)} of their {fmt_nm(whole)} RMS repeats "
        f"cycle to cycle, against {fmt_nm(noise)} of noise"
    )


def verdict_text(missing, physical, v0, noise, floor, at_floor, worst, ratio=None, held_out_ratio=None) -> str:
    """The verdict in words, with its tests' figures. 'complete' (no physical effect in the library is
    missing) says plainly whether the repeatable part is at the noise floor (≤ 2σ) or not, and if not,
    where it is worst. What to add next (physics or capacity) and what remains described are the
    answer's (service.science.discovery.answer), printed beside it: not repeated here."""
    if missing:
        top = physical[0]
        tested = ""
        if top.get("tested_rms_um") is not None and top["reference"]:
            tested = (
                f"the model + {' + '.join(top['reference'])} {fmt_nm(top['reference_rms_um'])} → "
                f"{fmt_nm(top['tested_rms_um'])} with it; "
            )
        alone = ""
        if top["expected_rms_um"] >= v0 - (v0 - noise) * ALONE_GAIN_SHARE:  # its own gain hides in loop shape
            alone = (
                f" (alone it gains little here: the rest is a loop shape this model cannot draw; add "
                f"{' and '.join(top['reference'])} as well)"
                if top["reference"]
                else ""
            )
        return (
            f"missing effect: {top['effect']} (p = {top['p_value']:.2g}; {tested}this model's held-out "
            f"{fmt_nm(v0)} → {fmt_nm(top['expected_rms_um'])} with it added{alone}); "
            f"held-out RMS {fmt_nm(v0)} against a noise floor of {fmt_nm(noise)}"
        )
    if at_floor:
        text = (
            f"complete: the held-out residual {fmt_nm(v0)} is at the noise floor in every block ("
            f"{repeated_words(floor, noise)}; at most {ratio:.1f}× a block's own noise)"
        )
    elif ratio is not None and ratio <= CLEAR_DROP_NOISE:
        where = f"; worst: {worst[0]['text']}" if worst and worst[0].get("text") else ""
        text = (
            f"complete as far as the effects library goes, but NOT at the noise floor: the held-out residual "
            f"{fmt_nm(v0)} is {held_out_ratio:.1f}× the {fmt_nm(noise)} of noise, although the repeated "
            f"cycles are within {ratio:.1f}× their own noise — the error is not a shape repeated cycle to cycle: it "
            f"lies in what changes between cycles (a block's first cycles, holds or amplitude changes where the "
            f"record has them, or a slow change over the record). No physical effect in the library removes it{where}"
        )
    else:
        where = f"; worst: {worst[0]['text']}" if worst and worst[0].get("text") else ""
        per_block = (
            f"up to {ratio:.1f}× a block's own noise"
            if ratio is not None
            else "no block's own noise could be measured: none repeats a cycle, or none shows any noise"
        )
        text = (
            f"complete as far as the effects library goes, but NOT at the noise floor: the held-out residual is "
            f"{fmt_nm(v0)}; {repeated_words(floor, noise)} ({per_block}). No physical "
            f"effect in the library removes it: it is the hysteresis model's own shape or an effect "
            f"outside the library{where}"
        )
    return text  # the capacity that would help is the answer's (answer.py), not repeated here
