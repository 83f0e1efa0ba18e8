"""A diagnosis's fits and its candidates' rows: ``DiagnosisFits`` (the model + any effects, each
fitted once on the diagnosis's records), ``candidate_row`` (a candidate's claim, score and evidence in
words) and ``claimed_size`` (the figure a row's score is of). Units: µm, µm² (nm in the texts).
Pure numpy: no store, no HTTP."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.science.data.units import fmt_nm
from service.science.discovery.composite import CompositeModel
from service.science.discovery.decision import held_out_improvement, less_gain_change
from service.science.discovery.verdict import score_capped, score_words, share_words, test_words
from service.science.effects import EFFECTS
from service.science.fitting.validation import evaluate_records


class DiagnosisFits:
    """Composite fits of one diagnosis, each fitted once (warm-started at the model's transforms)."""

    def __init__(self, records, model: CompositeModel):
        self.records, self.model, self._cache = records, model, {}

    def get(self, effects, theta: dict | None = None) -> tuple[CompositeModel, list[np.ndarray], float]:
        """The model + ``effects``: fitted, its residuals and held-out RMS. The model's transforms are
        kept, and so are ``theta`` (transforms an earlier fit found: a transform's whole search on the
        flexible base costs ten fits), but a row-local one's (a delay's) are refined from there: found on
        a PI that cannot draw a foreign stage's loop, a delay stayed 30 % short and lost to rate
        dependence. A mode's come from its harmonics above the drive band, which the loop's shape
        hardly moves (refining them too cost 60 % more per diagnosis)."""
        key = tuple(sorted(set(self.model.effects) | set(effects)))
        if key not in self._cache:
            local = {k: v for k, v in (theta or {}).items() if EFFECTS[k].row_local}
            held = {**self.model.theta, **{k: v for k, v in (theta or {}).items() if k not in local}}
            m = (
                self.model
                if set(key) == set(self.model.effects)
                else CompositeModel(list(key), self.model.n_operators, fixed_theta=held, local_theta=local).fit(
                    self.records
                )
            )
            preds = [m.predict(r) for r in self.records]
            held_out_um = evaluate_records(self.records, preds)["validation_rms_um"]
            self._cache[key] = (m, [r.x_um - p for r, p in zip(self.records, preds)], held_out_um)
        return self._cache[key]

    def without(self, effects, frequency_hz: float) -> list[np.ndarray]:
        """The residuals of the model + ``effects`` fitted without the blocks at ``frequency_hz``
        (the model's transforms kept)."""
        m = CompositeModel(
            sorted(set(self.model.effects) | set(effects)),
            self.model.n_operators,
            fixed_theta=self.model.theta,
            exclude_frequency_hz=frequency_hz,
        ).fit(self.records)
        return [r.x_um - m.predict(r) for r in self.records]


@dataclass(frozen=True)
class EffectTest:
    """``name`` tested against ``reference`` (effects beside the model) on a diagnosis's fits: the held-out
    ``test`` (decision.held_out_improvement), the plain residuals of both fits (µm, per record), their
    held-out RMS (µm), and ``words``: "against … (held-out RMS …), adding … gives … (figures)"."""

    test: dict
    raw_ref: list
    raw_trial: list
    v_ref: float
    v_trial: float
    words: str


def effect_test(name: str, reference: tuple, judged: Judged) -> EffectTest:
    """The model + ``reference`` + ``name`` against the model + ``reference``, by the diagnosis's rule: a
    transform's (or a drive stage's) parameters are those found on the model with it alone; a time effect
    (``gain_change_test``) is tested on residuals less a gain that changes with time, and its words say so
    (a walk read two "at its training mean" pairs, 356 of 392 nm² and 347 of 383 nm², in one paragraph:
    the test's and the size's, which is of the plain residuals)."""
    fits, records, eff = judged.fits, judged.records, EFFECTS[name]
    _, raw_ref, v_ref = fits.get(reference)
    theta = fits.get((name,))[0].theta if eff.stage in ("transform", "drive") else None
    _, raw_trial, v_trial = fits.get(reference + (name,), theta)
    res_ref, res_trial = raw_ref, raw_trial
    beyond = " "
    if eff.gain_change_test:
        res_ref, res_trial = less_gain_change(records, res_ref), less_gain_change(records, res_trial)
        beyond = " — both residuals less a gain that changes linearly with time, fitted on the training rows — "
    test = held_out_improvement(records, res_ref, res_trial)
    against = "the model" if not reference else "the model + " + " + ".join(reference)
    words = (
        f"against {against} (held-out RMS {fmt_nm(v_ref)}), adding {name} gives {fmt_nm(v_trial)}{beyond}"
        f"{test_words(test, judged.noise)}"
    )
    return EffectTest(test, raw_ref, raw_trial, v_ref, v_trial, words)


def claimed_size(test: dict, is_claimed: bool) -> tuple[float, str, float | None]:
    """The held-out mean-square drop (µm²) a row's score and words are of, its anchoring, and the whole
    it is a part of (the reference's own held-out mean square at that anchoring, µm²; None where the
    test gives none): a claim rests on the anchoring its p is of (the larger size), so a claim is never
    printed with the other anchoring's figure (drift was claimed at its training mean with −1.15 nm² and
    score 0 printed); a candidate not claimed, at the last training cycle, as every row's was."""
    anchor = test["p_anchor"] if is_claimed else "last_cycle"
    trend = anchor == "training_mean"
    drop = test["gain_trend_mse_um2"] if trend else test["gain_mse_um2"]
    return drop, anchor, test.get("reference_trend_mse_um2" if trend else "reference_mse_um2")


def score_sentence(score: float, anchor: str, capped: bool = False) -> str:
    """Which figure a row's score is, beside the share its evidence prints of adding it (a share of one
    anchoring, the score of another: "score 0" stood beside "34 % of the excess" with nothing saying so);
    ``capped``: a 1 that is a cap, said so here too (the Discover card shows this sentence alone)."""
    level = "its training mean" if anchor == "training_mean" else "its last training cycle"
    cap = " (capped: its test removed more than this model's excess above the noise floor)" if capped else ""
    return (
        f"the score, {score:.3g}{cap}, is its own test's share, a fit of its own with each block's level anchored at "
        f"{level}"
    )


@dataclass(frozen=True)
class Judged:
    """What every candidate row of one diagnosis is judged against: its ``fits`` on ``records``, the
    noise floor ``noise`` (µm; ``floor``, its figures), this model's held-out RMS ``v0`` (µm) and number
    of parameters ``k0``, and the residual's signature measures ``sig``."""

    fits: DiagnosisFits
    records: list
    noise: float
    v0: float
    k0: int
    sig: dict
    floor: dict


def candidate_row(
    name,
    judged: Judged,
    is_claimed: bool,
    p_value: float,
    gain: float,
    reference: tuple,
    v_ref: float,
    how: str,
    v_trial: float | None = None,
    kind: str | None = None,
    anchor: str = "last_cycle",
    whole_um2: float | None = None,
) -> dict:
    """A candidate's row: the claim, its evidence in words, and what adding it to this model gives
    (``v_trial``: the held-out RMS of its reference with it, where it was tested against one;
    ``kind``: "capacity" where this model makes a physical effect's columns capacity; ``whole_um2``: the
    reference's held-out mean square at ``anchor``, the whole ``gain`` is a part of, where known)."""
    fits, noise, v0, k0, sig, floor = judged.fits, judged.noise, judged.v0, judged.k0, judged.sig, judged.floor
    eff = EFFECTS[name]
    kind = kind or eff.kind
    v, added, fitted = v0, 0, ""
    if is_claimed or kind == "capacity":
        own, _, v = fits.get((name,))  # what the user gets by adding it to this model
        added, fitted = own.n_parameters() - k0, own.describe().get(name) or ""
    excess = max(v0**2 - noise**2, 1e-30)  # this model's held-out mean square above the floor (µm²)
    removed = min((v0**2 - v**2) / excess, 1.0)  # below the floor: all of the excess
    words = eff.evidence(sig, floor)
    score = round(float(np.clip(gain / excess, 0, 1)), 4)
    evidence = (
        (
            f"In this model's residual, before any fit: {words}. "
            if words
            else "No measure of its signature is taken before a fit. "
        )
        + f"Its test, a fit of its own: {how}"
        + (
            f". Added to this model: {fmt_nm(v0)} → {fmt_nm(v)} ({share_words(removed)} by adding it, levels not "
            f"anchored; {score_sentence(score, anchor, score_capped(gain, excess))})"
            if v != v0
            else ". Not claimed, so not fitted into this model"
        )
        + (
            f"; the diagnosis's own fit of this model + {name} gives {fitted} (a refine refits it, so the stored "
            "model's parameters may differ)"
            if fitted
            else ""
        )
        + "."
    )
    return {
        "effect": name,
        "kind": kind,
        "testable": True,
        "claimed": bool(is_claimed),
        "high": bool(is_claimed),
        "significant": bool(is_claimed),
        # one denominator for every candidate (this model's excess), so that scores rank as gains do
        "score": score,
        "score_of": score_words(gain, excess, reference, anchor),
        "score_capped": score_capped(gain, excess),
        "p_value": p_value,
        "gain_mse_um2": gain,
        "reference_mse_um2": whole_um2,
        "reference": list(reference),
        "reference_rms_um": v_ref,
        "tested_rms_um": v_trial,
        "expected_rms_um": v,
        "excess_removed": round(float(removed), 4),
        "added_parameters": added,
        "evidence": evidence,
        "signature": eff.signature,
    }
