"""The discovery test matrix (issue 17): hidden effects on several hysteresis families, clean
benches with collinear and independent drives, two and three effects at once.

    python -m service.reports.discovery_matrix [--seeds 0] [--clean-seeds 0 1 … 9] [--json matrix.json] [--markdown]
    python -m service.reports.discovery_matrix --from-json matrix.json      # the tables again, no run

Each case runs the paper's 1/10/50/100 Hz sine sweep (5 cycles) on an emulated bench and diagnoses
a fresh hysteresis model, as a user would over REST. Figures:

* **one hidden effect**: is the top candidate the hidden effect and claimed, and by how much does
  the refine (model + that effect) cut the held-out RMS;
* **clean benches** (nothing hidden; Preisach, Bouc–Wen and Maxwell-slip families; axes driven one
  after the other, or together with the same waveform): the share of diagnoses that claim any
  physical effect — the false-claim rate of the claim rule (service.science.discovery.decision);
* **several effects**: diagnose, add the top claimed effect, diagnose again: are all hidden effects
  named within as many rounds as there are effects.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from scipy import stats

from service.lab.emulated import sweep_records
from service.science.discovery.composite import fit_composite
from service.science.discovery.diagnosis import diagnose

EFFECTS = (
    "rate_dependence",
    "creep",
    "dynamics",
    "delay",
    "cross_coupling",
    "drift",
    "asymmetry",
    "sensor_nonlinearity",
)
FAMILIES = {"preisach": "", "bouc_wen": "bw_", "maxwell_slip": "ms_"}
SEVERAL = {
    "two_rate_dependence_creep": ("rate_dependence", "creep"),
    "two_dynamics_drift": ("dynamics", "drift"),
    "two_delay_cross_coupling": ("delay", "cross_coupling"),
    "two_asymmetry_creep": ("asymmetry", "creep"),
    "three_creep_dynamics_cross_coupling": ("creep", "dynamics", "cross_coupling"),
}
CLEAN = {"preisach": "base", "bouc_wen": "bw_base", "maxwell_slip": "ms_base"}


def _claims(d: dict) -> list[str]:
    return [c["effect"] for c in d["candidates"] if c.get("claimed") and c["kind"] == "physical"]


def one_effect(bench: str, effect: str, seed: int = 0, axis: str = "y") -> dict:
    """Top candidate and the refine's held-out drop for one hidden-effect bench."""
    rec = sweep_records(bench, seed)[axis]
    d = diagnose([rec])
    top = d["candidates"][0]
    right = top["effect"] == effect and top.get("claimed", False)
    after = fit_composite([rec], [top["effect"]]).evaluate([rec])["validation_rms_um"] if top.get("claimed") else None
    return {
        "bench": bench,
        "effect": effect,
        "axis": axis,
        "seed": seed,
        "top": top["effect"],
        "claimed": _claims(d),
        "right": bool(right),
        "before_um": d["residual_rms_um"],
        "after_um": after,
        "drop": None if after is None else 1.0 - after / d["residual_rms_um"],
    }


def clean(bench: str, family: str, together: bool, seed: int) -> list[dict]:
    """Both axes of a clean bench: which physical effects were claimed (none is right)."""
    recs = sweep_records(bench, seed, together=together)
    out = []
    for axis, rec in recs.items():
        d = diagnose([rec])
        out.append(
            {
                "bench": bench,
                "family": family,
                "drives": "collinear" if together else "independent",
                "seed": seed,
                "axis": axis,
                "claimed": _claims(d),
                "not_testable": [c["effect"] for c in d["not_testable"]],
            }
        )
    return out


def several(bench: str, hidden: tuple[str, ...], seed: int = 0, axis: str = "y") -> dict:
    """Diagnose, add the top claimed effect, repeat: the effects named within len(hidden) rounds."""
    rec = sweep_records(bench, seed)[axis]
    effects, named = [], []
    for _ in range(len(hidden)):
        model = fit_composite([rec], effects)
        d = diagnose([rec], model=model)
        claims = _claims(d)
        if not claims:
            break
        named.append(claims[0])
        effects.append(claims[0])
    return {"bench": bench, "hidden": list(hidden), "named": named, "all_named": set(hidden) <= set(named)}


def _logged(row):
    print(json.dumps(row, default=str), file=sys.stderr, flush=True)
    return row


def run(seeds=(0,), families=tuple(FAMILIES), clean_seeds=(0, 1, 2, 3)) -> dict:
    t0 = time.perf_counter()
    singles = [
        _logged(one_effect(prefix + e, e, seed))
        for prefix in (FAMILIES[f] for f in families)
        for e in EFFECTS
        for seed in seeds
    ]
    cleans = [
        _logged(row)
        for f in families
        for together in (False, True)
        for seed in clean_seeds
        for row in clean(CLEAN[f], f, together, seed)
    ]
    multi = [_logged(several(b, h)) for b, h in SEVERAL.items()]
    false_claims = sum(1 for c in cleans if c["claimed"])
    return {
        "one_effect": singles,
        "clean": cleans,
        "several": multi,
        "false_claim_rate": false_claims / max(len(cleans), 1),
        "clean_diagnoses": len(cleans),
        "seconds": time.perf_counter() - t0,
    }


def false_claim_upper_bound(claims: int, diagnoses: int, confidence: float = 0.95) -> float:
    """The one-sided Clopper–Pearson upper bound of a false-claim rate seen as ``claims`` of
    ``diagnoses`` (0 of 60 gives 4.9 %: about 60 clean diagnoses without a claim show ≤ 5 %)."""
    if diagnoses <= 0:
        return 1.0
    if claims >= diagnoses:
        return 1.0
    return float(stats.beta.ppf(confidence, claims + 1, diagnoses - claims))


def markdown(result: dict) -> str:
    rows = [
        "| bench | hidden | top candidate | claimed | held-out before → after refine (nm) | drop |",
        "|---|---|---|---|---|---|",
    ]
    for r in result["one_effect"]:
        after = "—" if r["after_um"] is None else f"{r['after_um'] * 1e3:.1f}"
        drop = "—" if r["drop"] is None else f"{100 * r['drop']:.0f} %"
        rows.append(
            f"| {r['bench']} | {r['effect']} | {'**' + r['top'] + '**' if r['right'] else r['top']} | "
            f"{', '.join(r['claimed']) or 'none'} | {r['before_um'] * 1e3:.1f} → {after} | {drop} |"
        )
    rows += ["", "| clean bench | drives | seed | axis | claimed | not testable |", "|---|---|---|---|---|---|"]
    for c in result["clean"]:
        rows.append(
            f"| {c['bench']} | {c['drives']} | {c['seed']} | {c['axis']} | {', '.join(c['claimed']) or 'none'} "
            f"| {', '.join(c['not_testable']) or '—'} |"
        )
    claims, n = round(result["false_claim_rate"] * result["clean_diagnoses"]), result["clean_diagnoses"]
    rows += [
        "",
        f"False-claim rate on clean benches: {result['false_claim_rate']:.1%} of {n} diagnoses "
        f"({claims} with a claim); one-sided 95 % upper bound (Clopper–Pearson) "
        f"{false_claim_upper_bound(claims, n):.1%}.",
        "",
        "| bench | hidden | named in order | all named |",
        "|---|---|---|---|",
    ]
    for m in result["several"]:
        rows.append(
            f"| {m['bench']} | {', '.join(m['hidden'])} | {', '.join(m['named']) or 'none'} | "
            f"{'yes' if m['all_named'] else 'no'} |"
        )
    return "\n".join(rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--clean-seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    parser.add_argument("--families", nargs="+", default=list(FAMILIES))
    parser.add_argument("--json", help="write the result here")
    parser.add_argument("--markdown", action="store_true", help="print the tables for docs/discovery-evidence.md")
    parser.add_argument("--from-json", help="print the tables of a result written earlier by --json (no run)")
    args = parser.parse_args(argv)
    if args.from_json:
        with open(args.from_json) as f:
            print(markdown(json.load(f)))
        return 0
    result = run(tuple(args.seeds), tuple(args.families), tuple(args.clean_seeds))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1, default=str)
    print(
        markdown(result)
        if args.markdown
        else json.dumps({k: result[k] for k in ("false_claim_rate", "clean_diagnoses", "seconds")}, indent=1)
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
