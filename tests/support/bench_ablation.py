"""What a model leaves on an emulated bench, physics by physics (issue 37 §3):
``python -m tests.support.bench_ablation --effects asymmetry,dynamics,... [--frequencies 10,100]
[--variants none creep_off ...]`` records the sine sweep of both axes one after the other on the
bench with one emulated physics switched off per variant, fits ``hysteresis + effects`` on the
axis and prints its held-out RMS per block (nm). Where switching a physics off lowers the figure,
that physics is part of what the model leaves. ``--store DIR --datasets ID,ID`` fits the same
effects on datasets a service stored (a discover run's, its experiments' included) instead.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from service.lab.emulated import sweep_records
from service.science.discovery.composite import fit_composite
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


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--bench", default="default")
    ap.add_argument("--axis", default="y", choices=["y", "z"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--effects", required=True, help="comma-separated effects beyond hysteresis")
    ap.add_argument("--frequencies", default="10,100")
    ap.add_argument("--cycles", type=int, default=5)
    ap.add_argument("--variants", nargs="*", default=["none"], choices=sorted(VARIANTS))
    ap.add_argument("--store", default=None, help="a service's data directory (with --datasets)")
    ap.add_argument("--datasets", default=None)
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
        rms, blocks, theta = held_out(records, effects)
        print(
            f"{name:<14} held-out {rms:6.2f} nm  per block {np.round(blocks, 1).tolist()}  {theta}  {time.time() - t:.0f} s"
        )


if __name__ == "__main__":
    main()
