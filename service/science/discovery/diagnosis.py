"""Which effect is missing: every candidate not in the model is fitted with it (training
cycles) and scored on the held-out cycles; the verdict, the ambiguity between close
candidates, and the experiment (a ready-to-POST sweep body) that separates them.

score = g · min(1, Δ/2σ) − 0.002·k, clipped to [0, 1], where g = (v₀² − v²)/(v₀² − σ²) is the
validated fraction of the excess (above the noise floor σ) that the candidate removes, Δ = v₀ − v
the held-out RMS drop (a drop smaller than 2σ counts proportionally less)
and k its added parameters (Occam: the simpler of two equal explanations ranks first).
"""
from __future__ import annotations

import numpy as np

from service.science.discovery.breakdown import failures, signatures
from service.science.discovery.composite import CompositeModel
from service.science.discovery.noise import noise_floor
from service.science.effects import EFFECTS

#: a score above this claims the effect is missing
HIGH_SCORE = 0.45
PARAMETER_PENALTY = 0.002
#: with several effects missing, one removes only part of the excess: a drop of ≥ 2σ that removes at
#: least this share of the excess is significant too (``significant``), and the verdict counts it
SIGNIFICANT_SHARE = 0.25
#: a held-out drop smaller than this many noise floors counts proportionally less (2-sigma rule)
CLEAR_DROP_NOISE = 2.0


def _fmt_nm(v_um) -> str:
    return f"{v_um * 1e3:.3g} nm"


def _signature_words(name: str, sig: dict, floor: dict) -> str:
    g = sig.get("rms_growth_exponent")
    growth = f"the residual grows with frequency as f^{g:.2f}" if g is not None else "frequency growth unknown"
    if name == "delay":
        if sig.get("lag_ms") is None:
            return "no lag can be measured: the model's prediction does not move in any block"
        per = ", ".join(f"{k} Hz: {v:.3g}" for k, v in sig["lag_ms_by_frequency"].items())
        spread = sig.get("lag_ms_spread")
        return (f"the residual lags the drive by {sig['lag_ms']:.3g} ms (slope-weighted mean; per block {per} ms, spread "
                f"{spread if spread is None else f'{spread:.2g}'} ms): delay")
    if name == "rate_dependence":
        r = sig.get("rate_r")
        return f"{growth}, and follows u̇·u (|r| = {r:.2f}): rate dependence" if r is not None else growth
    if name == "dynamics":
        return f"{growth}: a resonance above the drive band"
    if name == "creep":
        v = sig.get("cycle_mean_um_per_decade")
        return ("the per-cycle mean residual moves " + (_fmt_nm(v) if v is not None else "?") +
                " per decade of time within each block, logarithmic in time: creep")
    if name == "drift":
        v = sig.get("cycle_mean_trend_um_per_s")
        return ("the per-cycle mean residual keeps moving at " + (f"{v * 1e3:.3g} nm/s" if v is not None else "?") +
                " over the run: drift")
    if name == "asymmetry":
        v = sig.get("even_fraction")
        return (f"a parabola in the drive carries {100 * v:.0f} % of the loop residual (even, not point-symmetric): "
                "asymmetry" if v is not None else "asymmetry")
    if name == "cross_coupling":
        r = sig.get("coupling_r")
        return (f"this axis's residual follows the other axis's drive, r = {r:.2f}: cross-coupling" if r is not None
                else "no block drives the other axis alone, so coupling cannot be seen directly")
    if name == "operators":
        rep, nf = floor.get("repeatable_rms_um"), floor.get("noise_floor_um")
        return (f"the residual repeats cycle to cycle ({_fmt_nm(rep or 0)} repeatable vs {_fmt_nm(nf or 0)} noise): "
                "the loop shape needs more hysteresis capacity (finer play operators) — not a physical effect")
    return ""


def score_candidate(v0: float, v: float, noise: float, added: int) -> float:
    excess2 = max(v0**2 - noise**2, 1e-30)
    gain = float(np.clip((v0**2 - v**2) / excess2, 0.0, 1.0))
    clear = min(1.0, max(v0 - v, 0.0) / max(CLEAR_DROP_NOISE * noise, 1e-12))
    return float(np.clip(gain * clear - PARAMETER_PENALTY * added, 0, 1))


def diagnose(records, effects=(), n_operators: int = 10, model: CompositeModel | None = None) -> dict:
    """The diagnosis of ``hysteresis + effects`` on ``records`` (fitted here unless ``model``)."""
    records = list(records)
    model = model or CompositeModel(effects, n_operators).fit(records)
    preds = [model.predict(r) for r in records]
    res = [r.x_um - p for r, p in zip(records, preds)]
    ev = model.evaluate(records)
    v0 = ev["validation_rms_um"]
    floor = noise_floor(records, res)
    noise = floor["noise_floor_um"] or 0.0
    sig = signatures(records, res, preds)
    k0 = model.n_parameters()
    candidates = []
    for name, eff in EFFECTS.items():
        if name in model.effects:
            continue
        trial = CompositeModel(model.effects + [name], model.n_operators).fit(records, fixed_theta=model.theta)
        v = trial.evaluate(records)["validation_rms_um"]
        score = score_candidate(v0, v, noise, trial.n_parameters() - k0)
        removed = 100 * (v0**2 - v**2) / max(v0**2 - noise**2, 1e-30)
        significant = bool(v0 - v >= CLEAR_DROP_NOISE * noise and removed >= 100 * SIGNIFICANT_SHARE)
        fitted = trial.describe().get(name) or ""
        evidence = (f"{_signature_words(name, sig, floor)}. With {name}, held-out RMS {v0:.4g} → {v:.4g} µm "
                    f"({removed:.0f} % of the excess above the {noise:.3g} µm noise floor)"
                    + (f"; fitted {fitted}" if fitted else "") + ".")
        candidates.append({"effect": name, "kind": eff.kind, "score": round(score, 4), "expected_rms_um": v,
                           "excess_removed": round(removed / 100, 4),
                           "added_parameters": trial.n_parameters() - k0, "evidence": evidence,
                           "significant": significant,
                           "signature": eff.signature})
    for c in candidates:
        c["high"] = c["score"] >= HIGH_SCORE or c["significant"]
    # Capacity can absorb any repeatable residual, physics included: a physical effect that is
    # claimed ranks before it; otherwise the order is by score.
    candidates.sort(key=lambda c: (not (c["kind"] == "physical" and c["high"]), -c["score"], c["expected_rms_um"]))
    physical = [c for c in candidates if c["kind"] == "physical"]
    missing = bool(physical) and physical[0]["high"]
    repeatable = floor["repeatable_rms_um"]
    ratio = worst_repeatable_to_noise(floor["per_block"])
    # Both: every block's repeatable part within 2σ of its own noise, and the held-out residual
    # within √(1 + 2²)σ (residual² = repeatable² + σ²). The second catches what the cycle-to-cycle
    # figure cannot see: held-out stretches unlike any repeated cycle (amplitude ramps, holds).
    held_out_ratio = v0 / noise if noise > 0 else float("inf")
    at_floor = ratio is not None and ratio <= CLEAR_DROP_NOISE and held_out_ratio <= np.hypot(1.0, CLEAR_DROP_NOISE)
    worst = failures(records, res)
    return {"effects": ["hysteresis"] + model.effects, "residual_rms_um": v0, "train_rms_um": ev["train_rms_um"],
            "noise_floor_um": noise, "repeatable_rms_um": repeatable,
            "repeatable_to_noise": ratio, "held_out_to_noise": held_out_ratio, "at_noise_floor": bool(at_floor),
            "verdict": "missing_effect" if missing else "complete",
            "verdict_text": _verdict_text(missing, physical, candidates, v0, noise, repeatable, at_floor, worst, ratio,
                                          held_out_ratio),
            "candidates": candidates, "failures": worst, "signature": sig,
            "ambiguity": ambiguity(physical, records, noise), "noise": floor, "metrics": ev}


def worst_repeatable_to_noise(per_block: list[dict]) -> float | None:
    """The largest ratio over blocks of the repeatable part to that block's own noise: "at the noise
    floor" must hold at every frequency, not only on average."""
    ratios = [b["repeatable_um"] / b["noise_um"] for b in per_block
              if b.get("repeatable_um") is not None and b.get("noise_um") and np.isfinite(b["noise_um"])]
    return max(ratios) if ratios else None


def helpful_capacity(candidates) -> list[dict]:
    """Capacity candidates that remove a significant share of the excess on held-out data."""
    return [c for c in candidates if c["kind"] == "capacity" and c["excess_removed"] >= SIGNIFICANT_SHARE]


def _verdict_text(missing, physical, candidates, v0, noise, repeatable, at_floor, worst, ratio=None,
                  held_out_ratio=None) -> str:
    """The verdict in words. 'complete' (no physical effect in the library is missing) says plainly
    whether the repeatable part is at the noise floor (≤ 2σ) or not, and if not, where it is worst."""
    if missing:
        return (f"missing effect: {physical[0]['effect']} (score {physical[0]['score']:.2f}); held-out RMS "
                f"{v0:.4g} µm against a noise floor of {noise:.3g} µm")
    rep = "unknown" if repeatable is None else _fmt_nm(repeatable)
    if at_floor:
        text = (f"complete: the remaining {_fmt_nm(v0)} is at the noise floor in every block (repeatable part "
                f"{rep} against {_fmt_nm(noise)} of noise; at most {ratio:.1f}× a block's own noise)")
    elif ratio is not None and ratio <= CLEAR_DROP_NOISE:
        where = f"; worst: {worst[0]['text']}" if worst and worst[0].get("text") else ""
        text = (f"complete as far as the effects library goes, but NOT at the noise floor: the held-out residual "
                f"{_fmt_nm(v0)} is {held_out_ratio:.1f}× the {_fmt_nm(noise)} of noise, although the repeated "
                f"cycles are within {ratio:.1f}× their own noise — the error is where the drive does not "
                f"repeat (amplitude changes, holds). No physical effect in the library removes it{where}")
    else:
        where = f"; worst: {worst[0]['text']}" if worst and worst[0].get("text") else ""
        text = (f"complete as far as the effects library goes, but NOT at the noise floor: {rep} of the "
                f"remaining {_fmt_nm(v0)} repeats cycle to cycle against {_fmt_nm(noise)} of noise (up to "
                f"{ratio if ratio is not None else float('nan'):.1f}× a block's own noise). No physical "
                f"effect in the library removes it: it is the hysteresis model's own shape or an effect "
                f"outside the library{where}")
    cap = helpful_capacity(candidates)
    if cap:
        text += (f"; more hysteresis capacity ({cap[0]['effect']}) would remove {100 * cap[0]['excess_removed']:.0f} % "
                 f"of the excess (held-out {_fmt_nm(cap[0]['expected_rms_um'])}) — a model-capacity change, not physics")
    return text


#: pairs of effects that look alike on a sine sweep, and the experiment that separates them
SEPARATING = {
    frozenset(("creep", "drift")): ("a step-hold sweep up and down: creep relaxes logarithmically after each "
                                    "step and reverses when the drive steps down; drift keeps its direction "
                                    "and pace regardless of the steps",
                                    {"waveform": "step", "levels_v": [100.0, 20.0, 100.0, 20.0], "hold_s": 4.0}),
    frozenset(("delay", "rate_dependence")): ("a higher-frequency sine sweep: a delay is the same time at every "
                                              "frequency; rate dependence changes the loop shape with rate",
                                              {"waveform": "sine", "frequencies_hz": [100.0, 150.0, 200.0],
                                               "cycles": 10}),
    frozenset(("delay", "dynamics")): ("a higher-frequency sine sweep: a resonance amplifies towards f_n, a "
                                       "delay only shifts the phase", {"waveform": "sine", "frequencies_hz":
                                                                        [100.0, 150.0, 200.0], "cycles": 10}),
    frozenset(("rate_dependence", "dynamics")): ("a higher-frequency sine sweep: a resonance's gain rises as "
                                                 "f², rate dependence widens the loop",
                                                 {"waveform": "sine", "frequencies_hz": [100.0, 150.0, 200.0],
                                                  "cycles": 10}),
}


#: two leading candidates are told apart when the runner-up leaves at least this many times the
#: unexplained excess (held-out RMS² above the noise floor²) of the leader
SEPARATED_EXCESS_RATIO = 2.0


def remaining_excess(candidate: dict, noise: float) -> float:
    """What a candidate leaves unexplained above the noise floor (µm²), never below (σ/10)²."""
    return max(candidate["expected_rms_um"] ** 2 - noise**2, (0.1 * noise) ** 2)


def ambiguity(physical: list[dict], records, noise: float = 0.0) -> dict | None:
    """Two leading candidates that explain the residual about equally well (scores within 0.1 and
    the runner-up leaving less than twice the leader's unexplained excess), and the experiment."""
    if len(physical) < 2 or physical[1]["score"] < 0.3:
        return None
    a, b = physical[0], physical[1]
    ratio = remaining_excess(b, noise) / remaining_excess(a, noise)
    if a["score"] - b["score"] > 0.1 or ratio >= SEPARATED_EXCESS_RATIO:
        return None
    why, body = SEPARATING.get(frozenset((a["effect"], b["effect"])),
                               ("a multi-frequency sine sweep with more cycles per frequency",
                                {"waveform": "sine", "frequencies_hz": [1.0, 10.0, 50.0, 100.0], "cycles": 10}))
    axes = sorted({r.axis for r in records if r.axis}) or ["y"]
    return {"effects": [a["effect"], b["effect"]], "excess_ratio": ratio,
            "text": f"{a['effect']} and {b['effect']} explain the residual about equally well "
                    f"(scores {a['score']:.2f} and {b['score']:.2f}; held-out {_fmt_nm(a['expected_rms_um'])} and "
                    f"{_fmt_nm(b['expected_rms_um'])}); {why}",
            "experiment": {"axes": axes, **body}}
