"""What a model leaves on an emulated bench, physics by physics (issue 37 §3):
``python -m tests.support.bench_ablation --effects asymmetry,dynamics,... [--frequencies 10,100]
[--variants none creep_off ...]`` records the sine sweep of both axes one after the other on the
bench with one emulated physics switched off per variant, fits ``hysteresis + effects`` on the
axis and prints its held-out RMS per block (nm). Where switching a physics off lowers the figure,
that physics is part of what the model leaves. ``--store DIR --datasets ID,ID`` fits the same
effects on datasets a service stored (a discover run's, its experiments' included) instead.
``--anchors creep,drift`` instead tests those candidates against the model + the flexible base as
the diagnosis does (less a gain changing with time), and prints the claim test's p and size with
each block's level anchored at its last training cycle (the diagnosis's p) and at its training mean.
``--diagnose`` instead diagnoses the model ``hysteresis + effects`` as the diagnosis does and prints its
physical candidates in rank order (claimed, p, size in nm²: ``claim_size_um2`` where claimed).
``--loop`` instead runs the report's discovery loop (continue_past_ambiguity, as the discover job's test
compares it) from hysteresis and prints each step's held-out RMS against the noise floor.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from service.lab.emulated import sweep_records
from service.science.discovery import decision
from service.science.discovery.composite import CompositeModel, fit_composite
from service.science.fitting.validation import evaluate_records

#: one emulated physics off per variant (dotted keys of fixtures/benches/<bench>.toml), axis ``{a}``
VARIANTS = {
    "none": {},
    "rate_off": {"axes.{a}.piezo.rate_dependence.enabled": False},
    "creep_off": {"axes.{a}.piezo.creep.enabled": False},
    "flexure_off": {"axes.{a}.flexure.dynamics.enabled": False},
    "lags_off": {
        "axes.{a}.amplifier.bandwidth.enabled": False,
        "axes.{a}.gauge.bandwidth.enabled": False,
        "daq.latency.enabled": False,
    },
    "gauge_bow_off": {"axes.{a}.gauge.nonlinearity.enabled": False},
    "drift_off": {"axes.{a}.gauge.drift.enabled": False, "ambient.drift.enabled": False},
    "coupling_off": {"coupling.enabled": False},
    "asymmetry_off": {"axes.{a}.piezo.asymmetry.enabled": False},
}


def held_out(records, effects: list[str]) -> tuple[float, list[float], dict]:
    """``hysteresis + effects`` fitted on ``records``: held-out RMS (nm, mean over blocks), per block, theta."""
    model = fit_composite(records, effects, 10, {})
    ev = evaluate_records(records, [model.predict(r) for r in records])
    blocks = [b["validation"]["rms_um"] * 1e3 for d in ev["per_dataset"] for b in d["blocks"]]
    return ev["validation_rms_um"] * 1e3, blocks, model.theta


def anchored_tests(records, effects: list[str], candidates: list[str]) -> None:
    """Print each candidate's claim test over the model ``hysteresis + effects`` + the flexible base,
    on both anchors: p (one-sided signed-rank over the held-out segments) and size (nm²)."""
    from scipy import stats

    model = fit_composite(records, effects, 10, {})

    def residuals(extra):
        m = CompositeModel(sorted(set(effects) | set(extra)), 10, fixed_theta=model.theta).fit(records)
        return decision.less_gain_change(records, [r.x_um - m.predict(r) for r in records])

    ref = residuals(("operators", "asymmetry"))
    for name in candidates:
        trial = residuals(("operators", "asymmetry", name))
        test = decision.held_out_improvement(records, ref, trial)
        diffs = []
        for rec, r0, r1 in zip(records, ref, trial):
            for s in rec.splits:
                a = s.held_out[0]
                e0, e1 = decision.training_mean_free(r0, s), decision.training_mean_free(r1, s)
                for i, j in decision._segments(rec, s):
                    ms0, ms1 = np.mean(e0[i - a : j - a] ** 2), np.mean(e1[i - a : j - a] ** 2)
                    if abs(ms0 - ms1) > decision.TIE_SHARE * (ms0 + ms1):
                        diffs.append(ms0 - ms1)
        p_mean = float(stats.wilcoxon(np.array(diffs), alternative="greater").pvalue)
        print(
            f"{name}: last training cycle p = {test['p']:.2g}, size {test['gain_mse_um2'] * 1e6:.3g} nm²; "
            f"training mean p = {p_mean:.2g}, size {test['gain_trend_mse_um2'] * 1e6:.3g} nm²"
        )


def diagnosed(records, effects: list[str]) -> None:
    """Print the diagnosis of ``hysteresis + effects`` on ``records``: its physical candidates in rank order."""
    from service.science.discovery.diagnosis import diagnose

    d = diagnose(records, model=CompositeModel(effects, 10).fit(records))
    for c in d["candidates"]:
        if c["kind"] == "physical" and c.get("testable", True):
            size = c.get("claim_size_um2", c["gain_mse_um2"]) * 1e6
            print(f"  {c['effect']:<20} {'claimed' if c['claimed'] else '-':<8} p = {c['p_value']:.2g}, {size:.1f} nm²")


def loop(records) -> None:
    """Print the report loop's steps on ``records``: effects, held-out RMS and floor (nm), verdict."""
    from service.science.discovery.loop import discovery_run

    for k, step in enumerate(discovery_run(records, continue_past_ambiguity=True)):
        d = step["diagnosis"]
        rms, floor = d["residual_rms_um"] * 1e3, d["noise_floor_um"] * 1e3
        print(
            f"{k} {'+'.join(step['effects'])}: {rms:.2f} nm, floor {floor:.2f} nm ({rms / floor:.2f}x), {d['verdict']}"
        )


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--bench", default="default")
    ap.add_argument("--axis", default="y", choices=["y", "z"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--effects", default="", help="comma-separated effects beyond hysteresis")
    ap.add_argument("--loop", action="store_true", help="run the report's discovery loop instead")
    ap.add_argument("--diagnose", action="store_true", help="print the diagnosis of hysteresis + effects instead")
    ap.add_argument("--frequencies", default="10,100")
    ap.add_argument("--cycles", type=int, default=5)
    ap.add_argument("--variants", nargs="*", default=["none"], choices=sorted(VARIANTS))
    ap.add_argument("--store", default=None, help="a service's data directory (with --datasets)")
    ap.add_argument("--datasets", default=None)
    ap.add_argument("--anchors", default=None, help="candidates whose claim test to print on both anchors")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    effects = [e for e in args.effects.split(",") if e]
    if args.store:
        from service.store import Store
        from service.usecases.identify import load_records

        store = Store(f"sqlite:///{args.store}/evcbench.db", args.store)
        runs = [("stored", load_records(store, args.datasets.split(","), args.axis))]
    else:
        freqs = tuple(float(f) for f in args.frequencies.split(","))
        runs = []
        for name in args.variants:
            over = {k.format(a=args.axis): v for k, v in VARIANTS[name].items()}
            recs = sweep_records(args.bench, args.seed, frequencies_hz=freqs, cycles=args.cycles, overrides=over)
            runs.append((name, [recs[args.axis]]))
    for name, records in runs:
        t = time.time()
        if args.loop:
            loop(records)
            continue
        if args.diagnose:
            print(name)
            diagnosed(records, effects)
            continue
        if args.anchors:
            anchored_tests(records, effects, args.anchors.split(","))
            continue
        rms, blocks, theta = held_out(records, effects)
        print(
            f"{name:<14} held-out {rms:6.2f} nm  per block {np.round(blocks, 1).tolist()}  {theta}  {time.time() - t:.0f} s"
        )


if __name__ == "__main__":
    main()
