"""Which effect is missing: every candidate not in the model is fitted with it (training cycles)
and compared on the held-out cycles; the verdict, the ambiguity between close candidates, the
effects the data cannot test, and the experiment (a ready-to-POST sweep body) for each.

Three kinds of candidate, three references:
- a **physical** effect (rate dependence, creep, drift, delay, dynamics, coupling) is compared
  with the model plus a flexible rate-independent base (finer operators and a non-symmetric loop
  shape): what differs between frequencies, over time or with the other axis's independent motion
  is physics, a loop shape the paper's PI cannot draw is not;
- ``asymmetry`` (a loop that is not point-symmetric: electrostrictive or saturating) is compared
  with the model plus finer operators, which draw any point-symmetric loop;
- ``operators`` (capacity) is compared with the model itself, and is never physics.
The record's rests come first (service/science/discovery/rests.py): they give the noise floor, and a
line seen at rest (mains pickup) is reported as a disturbance and taken out of the record before the
model is judged, so that no loop shape is claimed for it. Each candidate must pass the family-wise
level split over the candidates tested (decision.candidate_alpha).
The claim rule and its false-claim basis: service/science/discovery/decision.py. Effects the data
cannot test (service/science/discovery/identifiability.py) are listed apart, never claimed.
"""

from __future__ import annotations

import numpy as np

from service.science.data.units import fmt_nm, fmt_nm2
from service.science.discovery.ambiguity import ambiguity
from service.science.discovery.answer import diagnosis_answer
from service.science.discovery.base_capacity import GOOD_ENOUGH_TO_NOISE, capacity_before_physics, later_grid
from service.science.discovery.breakdown import failures, signatures
from service.science.discovery.candidate_rows import (
    DiagnosisFits,
    Judged,
    candidate_row,
    claimed_size,
    effect_test,
)
from service.science.discovery.column_memo import shared_effect_columns
from service.science.discovery.composite import CompositeModel
from service.science.discovery.decision import (
    NOISE_MULTIPLE,
    candidate_alpha,
    claimed,
    rule_text,
    unseen_block_improvement,
)
from service.science.discovery.identifiability import not_testable
from service.science.discovery.loop_shape import LOOP_SHAPE, loop_shape_pair
from service.science.discovery.noise import noise_floor
from service.science.discovery.ranking import claim_size, rank_key, size_claims
from service.science.discovery.remainder import describe_remainder
from service.science.discovery.rests import LineFree, disturbance
from service.science.discovery.verdict import (
    CLEAR_DROP_NOISE,
    helpful_capacity,
    residual_words,
    verdict_text,
    worst_repeatable_to_noise,
)
from service.science.discovery.wider_base import judge_on_wider_base
from service.science.effects import EFFECTS
from service.science.fitting.validation import evaluate_records


def flexible_base() -> tuple[str, ...]:
    """The flexible rate-independent base that physical candidates must beat: the effects marked
    ``in_flexible_base`` (finer operators, then a non-symmetric loop shape), capacity first."""
    return tuple(
        sorted((n for n, e in EFFECTS.items() if e.in_flexible_base), key=lambda n: EFFECTS[n].kind != "capacity")
    )


# Candidates with ``unseen_rate_test`` (rate dependence) must also hold their claim at the drive rates
# between the others, fitted without them: rate dependence's per-segment rate terms give a loop
# branch-dependent shape freedom the base lacks, so after a mode (or on a loop the base cannot draw)
# they lowered the held-out error at frequencies they were fitted on, and made the blocks they had
# not seen worse (a user's foreign stages: 12 of 14 with a mode claimed it after dynamics); a rate
# effect predicts the frequencies between the ones it was fitted on (the emulated rate-dependent
# benches: +6000 nm² of mean square)


def offered(in_model) -> list[str]:
    """The effects a diagnosis of a model with effects ``in_model`` tests: those not in it, and not
    an alternative (``Effect.alternative_to``) to one in it."""
    have = set(in_model)
    return [n for n, e in EFFECTS.items() if n not in have and not have & set(e.alternative_to)]


#: a later grid of the base is tried only where the base's shape is what limits the model: an earlier
#: grid removes at least this share of the model's held-out excess over the noise floor (on a bench
#: whose residual is mostly physics, another grid has nothing to say yet, and each costs a fit)
BASE_LIMITS_SHARE = 0.5


def _alternative_not_needed(name: str, candidates: list[dict], noise: float) -> str | None:
    """Why ``name`` is not tried (in words), or None: an alternative to it, tested before it in this
    diagnosis, already leaves a held-out RMS within GOOD_ENOUGH_TO_NOISE × the noise floor, or
    removes less than BASE_LIMITS_SHARE of the model's excess (the base is not what limits it)."""
    earlier = [c for c in candidates if c["effect"] in set(EFFECTS[name].alternative_to)]
    for c in earlier:
        if c["expected_rms_um"] <= GOOD_ENOUGH_TO_NOISE * noise:
            return (
                f"{c['effect']} already leaves {fmt_nm(c['expected_rms_um'])} held out, within "
                f"{GOOD_ENOUGH_TO_NOISE:g} × the noise floor ({fmt_nm(noise)}); the smaller grid is kept"
            )
    if earlier and max(c["excess_removed"] for c in earlier) < BASE_LIMITS_SHARE:
        best = max(earlier, key=lambda c: c["excess_removed"])
        return (
            f"the base's shape is not what limits this model: {best['effect']} removes "
            f"{100 * best['excess_removed']:.0f} % of its excess over the noise floor"
        )
    return None


def _untested_row(name: str, why: dict, evidence: str, v0: float) -> dict:
    """A candidate row for an effect the diagnosis did not test (``why``: its ``effect``, ``reason``
    and any experiment), at the model's held-out RMS ``v0`` (µm)."""
    return {
        **why,
        "kind": EFFECTS[name].kind,
        "testable": False,
        "claimed": False,
        "high": False,
        "significant": False,
        "score": 0.0,
        "p_value": 1.0,
        "gain_mse_um2": 0.0,
        "expected_rms_um": v0,
        "excess_removed": 0.0,
        "added_parameters": 0,
        "evidence": evidence,
        "signature": EFFECTS[name].signature,
    }


def _reference_for(name: str) -> tuple[str, ...]:
    """What a candidate must beat: capacity the model itself; physics the flexible base."""
    return () if EFFECTS[name].kind == "capacity" else tuple(e for e in flexible_base() if e != name)


def _unseen_rates(name: str, fits: DiagnosisFits, records, reference: tuple) -> dict | None:
    """The mean drop in mean square (µm²) that ``name`` gives, over the reference, on the blocks at
    each drive frequency between the lowest and the highest when both were fitted without them
    (``gain_mse_um2``, ``frequencies_hz``); None without such a frequency."""
    freqs = sorted(
        {
            s.block["frequency_hz"]
            for r in records
            for s in r.splits_of(own_axis_only=True)
            if s.block.get("frequency_hz")
        }
    )
    gains = []
    for f in freqs[1:-1]:
        gains += unseen_block_improvement(records, fits.without(reference, f), fits.without(reference + (name,), f), f)
    return {"gain_mse_um2": float(np.mean(gains)), "frequencies_hz": freqs[1:-1]} if gains else None


def _candidate(name, judged: Judged, alpha: float) -> dict:
    """One testable candidate: its test against its reference, the claim, and what adding it to
    the model gives (fitted only when it is claimed or is capacity: the others change nothing)."""
    fits, records, noise, v0 = judged.fits, judged.records, judged.noise, judged.v0
    eff = EFFECTS[name]
    reference = _reference_for(name)
    tried = effect_test(name, reference, judged)
    test, how = tried.test, tried.words
    is_claimed = claimed(test, noise, alpha)
    unseen = _unseen_rates(name, fits, records, reference) if is_claimed and eff.unseen_rate_test else None
    if unseen is not None:
        rates = ", ".join(f"{f:g} Hz" for f in unseen["frequencies_hz"])
        kept = unseen["gain_mse_um2"] >= NOISE_MULTIPLE * noise**2
        drop = unseen["gain_mse_um2"]
        how += (
            f"; fitted, with its reference, without the {rates} blocks, it "
            + (
                f"lowers their mean square by {fmt_nm2(drop)}"
                if drop >= 0
                else f"raises their mean square by {fmt_nm2(-drop)}"
            )
            + f" (a claim needs a drop of at least σ² = {fmt_nm2(noise**2)}): "
            + (
                "it predicts rates it was not fitted on"
                if kept
                else "it does not predict rates it was not fitted on, so what it fits is loop shape, not a rate "
                "effect: not claimed"
            )
        )
        is_claimed = is_claimed and kept
    if is_claimed and eff.kind == "physical":
        v_alone = fits.get((name,))[2]
        if v_alone > v0:  # its gain over the flexible base is loop shape the base leaves (a clean Bouc–Wen
            # stage: drift 6.06 → 4.30 nm over the base, 47.1 → 55.9 nm added to the model)
            how += (
                f"; added to this model alone it raises the held-out RMS ({fmt_nm(v0)} → {fmt_nm(v_alone)}): what it "
                "fits over the flexible base is loop shape that base leaves, not this effect: not claimed"
            )
            is_claimed = False
    if is_claimed and eff.kind == "physical":  # one figure for the claim: its size, the rank's (ranking.py)
        (gain, whole), anchor = claim_size(records, tried.raw_ref, tried.raw_trial), "training_mean"
    else:
        gain, anchor, whole = claimed_size(test, is_claimed)
    return candidate_row(
        name,
        judged,
        is_claimed,
        test["p"],
        gain,
        reference,
        tried.v_ref,
        how,
        tried.v_trial,
        anchor=anchor,
        whole_um2=whole,
    )


def _seen_at_rest(name, judged: Judged, rests: dict, alpha: float) -> dict:
    """A disturbance the rests show (service/science/discovery/rests.py), already taken out of the record:
    claimed on the rests' held-out test (its strongest line's z, one-sided), its gain the lines' mean square."""
    from statistics import NormalDist

    z = max(line["z"] for line in rests["lines"])
    p = float(1.0 - NormalDist().cdf(z))
    gain = float(sum(line["amplitude_um"] ** 2 / 2 for line in rests["lines"]))
    how = (
        f"{disturbance(rests)['text']} (held-out z = {z:.3g} at rest against a threshold of "
        f"{rests['threshold_z']:.3g}, Bonferroni over {len(rests['tried'])} frequencies)"
    )
    return candidate_row(name, judged, p < alpha, p, gain, (), judged.v0, how)


def fitted_without_lines(line_free: LineFree, model: CompositeModel) -> CompositeModel:
    """``model`` (fitted on the records as recorded) as fitted on ``line_free``'s records: itself where
    the rests showed no lines, else refitted there with its transform parameters kept."""
    if not line_free.had_lines:
        return model
    return CompositeModel(model.effects, model.n_operators, fixed_theta=model.theta).fit(line_free.records)


def diagnose(records, effects=(), n_operators: int = 10, model: CompositeModel | None = None) -> dict:
    """The diagnosis of ``hysteresis + effects`` on ``records`` as recorded (fitted here unless
    ``model``, fitted on them): a line the rests show is a disturbance, not the model, so it is taken
    out of the records before the model is judged."""
    line_free = LineFree.of(records)
    if model is None:
        model = CompositeModel(effects, n_operators).fit(line_free.records)
    return diagnose_line_free(line_free, fitted_without_lines(line_free, model))


@shared_effect_columns()  # its dozen fits share each effect's columns of the same records
def diagnose_line_free(line_free: LineFree, model: CompositeModel) -> dict:
    """The diagnosis of ``model``, fitted on ``line_free.records`` (the records without the rests' lines)."""
    records, rests = line_free.records, line_free.rests
    fits = DiagnosisFits(records, model)
    _, res, v0 = fits.get(())
    preds = [r.x_um - e for r, e in zip(records, res)]
    ev = evaluate_records(records, preds)
    floor = noise_floor(records, res, rests)
    noise = floor["noise_floor_um"] or 0.0
    sig = signatures(records, res, preds)
    k0 = model.n_parameters()
    judged = Judged(fits, records, noise, v0, k0, sig, floor)
    candidates, untestable, not_tried, shape_ambiguity = [], [], [], None
    why_not_of = {name: not_testable(name, records) for name in offered(model.effects)}
    # alternatives (one base's grids) are one question of the family: counted once
    tested = sum(why is None and not later_grid(name) for name, why in why_not_of.items())
    alpha = candidate_alpha(tested)  # more candidates, the same family-wise false-claim rate
    for name, why_not in why_not_of.items():
        eff = EFFECTS[name]
        if eff.seen_at_rest and rests and rests["lines"]:  # seen at rest, and out of the record already
            candidates.append(_seen_at_rest(name, judged, rests, alpha))
            continue
        if why_not is not None:
            untestable.append(_untested_row(name, why_not, f"not testable: {why_not['reason']}", v0))
            continue
        enough = _alternative_not_needed(name, candidates, noise)
        if enough is not None:
            not_tried.append(_untested_row(name, {"effect": name, "reason": enough}, f"not tried: {enough}", v0))
            continue
        if name in LOOP_SHAPE and not set(LOOP_SHAPE) & set(model.effects):
            if name == LOOP_SHAPE[0]:  # the pair is weighed together, once
                pair, shape_ambiguity = loop_shape_pair(judged, alpha)
                candidates += pair
            continue
        candidates.append(_candidate(name, judged, alpha))
    at_rest = {n for n, e in EFFECTS.items() if e.seen_at_rest} if rests and rests["lines"] else set()
    size_claims(candidates, at_rest)  # one comparable size for every claim: ranking.py
    candidates.sort(key=rank_key)
    physical, missing, first = _claims(candidates, noise)
    if first is not None and judge_on_wider_base(candidates, judged, first["effect"], alpha):
        candidates.sort(key=rank_key)  # a claim the wider base does not confirm is no longer one
        physical, missing, first = _claims(candidates, noise)
    repeatable = floor["repeatable_rms_um"]
    ratio = worst_repeatable_to_noise(floor["per_block"])
    # Both: every block's repeatable part within 2σ of its own noise, and the held-out residual
    # within √(1 + 2²)σ (residual² = repeatable² + σ²). The second catches what the cycle-to-cycle
    # figure cannot see: held-out stretches unlike any repeated cycle (amplitude ramps, holds).
    held_out_ratio = v0 / noise if noise > 0 else float("inf")
    at_floor = ratio is not None and ratio <= CLEAR_DROP_NOISE and held_out_ratio <= np.hypot(1.0, CLEAR_DROP_NOISE)
    # ... and no capacity passes the claim rule: its held-out gain shows a repeatable model error the
    # two figures let through (a Coleman–Hodgdon stage under 10 nm of noise: 1.69× the floor held out,
    # "at the floor", while hysterons, claimed, held out 1.02×)
    at_floor = at_floor and not any(c["kind"] == "capacity" and c["claimed"] for c in candidates)
    worst = failures(records, res)
    remainder = None if at_floor else describe_remainder(records, res, preds, noise)
    between = ambiguity(physical, records, noise) or _leading(shape_ambiguity, physical)
    answer = diagnosis_answer(
        [c for c in physical if c["claimed"]],
        helpful_capacity(candidates),
        v0,
        noise,
        bool(at_floor),
        remainder,
        first,
        between,
    )
    disturbed = disturbance(rests)
    return {
        "effects": ["hysteresis"] + model.effects,
        "residual_rms_um": v0,
        "residual_of": residual_words(records),
        "train_rms_um": ev["train_rms_um"],
        "noise_floor_um": noise,
        "repeatable_rms_um": repeatable,
        "repeated_cycles_rms_um": floor.get("repeated_cycles_rms_um"),
        "repeatable_to_noise": ratio,
        "held_out_to_noise": held_out_ratio,
        "at_noise_floor": bool(at_floor),
        "verdict": "missing_effect" if missing else "complete",
        # the verdict and its tests' figures; what is missing or grows first, and what remains described,
        # are the answer's alone (the page and the report print both: neither repeats the other)
        "verdict_text": (f"{disturbed['text']}. " if disturbed else "")
        + verdict_text(missing, physical, v0, noise, floor, at_floor, worst, ratio, held_out_ratio),
        "disturbance": disturbed,
        "remainder": remainder,
        "answer": answer,
        "candidates": candidates + untestable + not_tried,
        "not_testable": untestable,
        "not_tried": [{"effect": c["effect"], "reason": c["reason"]} for c in not_tried],
        "claim_rule": rule_text(noise, tested),
        "candidates_tested": tested,
        "candidate_alpha": alpha,
        "failures": worst,
        "signature": sig,
        "ambiguity": between,
        "noise": floor,
        "metrics": ev,
    }


def _claims(candidates: list[dict], noise: float) -> tuple[list[dict], bool, dict | None]:
    """Of ranked ``candidates``: the physical rows, whether the top one is claimed (an effect is
    missing), and the capacity the loop adds before the physics (base_capacity.py), or None."""
    physical = [c for c in candidates if c["kind"] == "physical"]
    missing = bool(physical) and physical[0]["claimed"]
    verdict = "missing_effect" if missing else "complete"
    return (
        physical,
        missing,
        capacity_before_physics({"verdict": verdict, "noise_floor_um": noise, "candidates": candidates}),
    )


def _leading(pair_ambiguity: dict | None, physical: list[dict]) -> dict | None:
    """The loop-shape pair's ambiguity when it is about what to add next (its claimed one leads the
    physical candidates), else None: an ambiguity says which experiment the next step needs."""
    if pair_ambiguity is None or not physical or physical[0]["effect"] != pair_ambiguity["effects"][0]:
        return None
    return pair_ambiguity
