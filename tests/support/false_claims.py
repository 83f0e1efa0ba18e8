"""Issue 38 §4: the claim rule's false-claim rate per diagnosis on clean stages (nothing hidden), with
its one-sided 95 % Clopper–Pearson upper bound; and what the diagnosis claims on the hum and gain-fade
stages (tests/support/disturbed_stages.py).

    .venv/bin/python -m tests.support.false_claims [--worlds ...] [--forms blocks long]
        [--noise-nm 1 3 10] [--seeds 0 1] [--kinds clean hum gainfade] [--fs 5000] [--json out.json]

Each case: a fresh hysteresis model diagnosed (service.science.discovery.diagnosis.diagnose) on the
stage's records as imported. A false claim on a clean stage is any claimed candidate of kind
"physical" (capacity is a model's, never physics); on the hum stage any claim of a loop-shape or rate
effect (or capacity) is counted, on the gain-fade stage a claim of creep or drift.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings

from tests.support.disturbed_stages import KINDS, records
from tests.support.hysteresis_worlds import WORLDS

#: what a disturbed stage must not be claimed as
WRONG = {
    "clean": None,  # any physical claim
    "hum": {"asymmetry", "sensor_nonlinearity", "rate_dependence", "delay", "dynamics", "operators", "hysterons"},
    "gainfade": {"creep", "drift"},
}


def run_case(world: str, kind: str, form: str, noise_nm: float, seed: int, fs: float) -> dict:
    from service.science.discovery.diagnosis import diagnose

    recs = records(world, kind, form, noise_nm * 1e-3, seed, fs)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = diagnose(recs)
    claims = [c["effect"] for c in d["candidates"] if c["claimed"]]
    physical = [c["effect"] for c in d["candidates"] if c["claimed"] and c["kind"] == "physical"]
    wrong = physical if WRONG[kind] is None else [e for e in claims if e in WRONG[kind]]
    top = ((d.get("remainder") or {}).get("signatures") or [{}])[0]
    return {
        "world": world,
        "kind": kind,
        "form": form,
        "noise_nm": noise_nm,
        "seed": seed,
        "claimed": claims,
        "false": wrong,
        "floor_nm": d["noise_floor_um"] * 1e3,
        "held_out_nm": d["residual_rms_um"] * 1e3,
        "disturbance": [
            (round(li["frequency_hz"], 2), round(li["amplitude_um"] * 1e3, 2))
            for li in (d.get("disturbance") or {}).get("lines", [])
        ],
        "leading_signature": top.get("signature"),
        "leading_text": top.get("text"),
        "seconds": time.perf_counter() - t0,
    }


def upper_bound(false: int, n: int, confidence: float = 0.95) -> float:
    """One-sided Clopper–Pearson upper bound of a rate seen ``false`` times in ``n``."""
    from scipy import stats

    return 1.0 if false >= n else float(stats.beta.ppf(confidence, false + 1, n - false))


def summary(rows: list[dict]) -> dict:
    out = {}
    for kind in sorted({r["kind"] for r in rows}):
        mine = [r for r in rows if r["kind"] == kind]
        k = sum(1 for r in mine if r["false"])
        out[kind] = {"diagnoses": len(mine), "false": k, "rate": k / len(mine), "upper_95": upper_bound(k, len(mine))}
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--worlds", nargs="*", default=list(WORLDS))
    ap.add_argument("--kinds", nargs="*", default=["clean"], choices=KINDS)
    ap.add_argument("--forms", nargs="*", default=["blocks", "long"])
    ap.add_argument("--noise-nm", nargs="*", type=float, default=[1.0, 3.0, 10.0])
    ap.add_argument("--seeds", nargs="*", type=int, default=[0, 1])
    ap.add_argument("--fs", type=float, default=5000.0)
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    rows = []
    for kind in args.kinds:
        for world in args.worlds:
            for form in args.forms:
                for noise in args.noise_nm:
                    for seed in args.seeds:
                        rows.append(run_case(world, kind, form, noise, seed, args.fs))
                        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    result = {"rows": rows, "summary": summary(rows), "fs": args.fs}
    print(json.dumps(result["summary"], indent=1))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=1)


if __name__ == "__main__":
    main()
