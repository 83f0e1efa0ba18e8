"""The one-call discovery on an emulated bench, over REST as a user runs it (issue 37 §3):
``python -m service.reports.discover_bench [--bench default] [--axis y] [--seed 0] [--json FILE]``.

A fresh service (its own data directory, the bench in process) records the 1/10/50/100 Hz sine
sweep of both axes one after the other (POST /api/sweeps ``{"axes": ["y", "z"], "together":
false}``), fits ``hysteresis`` on the axis (POST /api/models) and runs POST
/api/models/{id}/discover ``{"allow_experiments": true}`` with its defaults. Prints each step's
held-out RMS as fitted, like for like (on every dataset the run ended with) and on the original
data, the noise floor, the effects tried and not kept, the experiments (cut to the bench or skipped)
and how it stopped."""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import warnings

from fastapi.testclient import TestClient

from service.frontends.client import Client
from service.http.app import create_app
from service.render.text import step_change
from service.runtime.settings import Settings
from service.science.data.units import fmt_nm


def run(bench: str, axis: str, seed: int = 0) -> dict:
    """The discover job's result on a fresh service of emulated ``bench``, from ``axis``'s hysteresis."""
    data_dir = tempfile.mkdtemp(prefix="evc-discover-")
    app = create_app(Settings(data_dir=data_dir, bench=bench, seed=seed, engine="inline", auth="off"))
    with TestClient(app) as http:
        api = Client(http=http, timeout_s=7200)
        sweep = api.wait(http.post("/api/sweeps", json={"axes": ["y", "z"], "together": False}).json()["job_id"])
        fit = http.post(
            "/api/models", json={"axis": axis, "datasets": [sweep["result"]["dataset_id"]], "effects": ["hysteresis"]}
        )
        model_id = api.wait(fit.json()["job_id"])["result"]["model_id"]
        job = api.discover(model_id, allow_experiments=True)
    return {"state": job["state"], "error": job.get("error"), **(job.get("result") or {})}


def table(result: dict) -> str:
    """The run as text: one line per step, then the experiments and the stop."""
    lines = ["step  change               held-out   like for like   original data   noise floor"]
    for s in result.get("steps", []):
        change = step_change(s) or ("+data" if s["experiment_dataset_id"] else "start")
        lines.append(
            f"{s['step']:>4}  {change:<20} {fmt_nm(s['validation_rms_um'], 4):>9}  "
            f"{fmt_nm(s['like_for_like_rms_um'], 4):>13}  {fmt_nm(s['original_data_rms_um'], 4):>14}  "
            f"{fmt_nm(s['noise_floor_um'], 3):>11}"
        )
        lines += [f"      tried next: {r['text']}" for r in s["not_kept"]]
    for e in result.get("experiments", []):
        cut = f", cut: {'; '.join(e['cut_to_bench'])}" if e["cut_to_bench"] else ""
        lines.append(f"experiment for {'/'.join(e['effects'])} after step {e['after_step']}: {e['experiment']}{cut}")
    for e in result.get("suggested_experiments", []):
        lines.append(f"not run, for {'/'.join(e['effects'])}: {e['not_run_because']}")
    remains = result.get("remains") or {}
    lines.append(
        f"state {result['state']}, stopped {result.get('stopped')}: {fmt_nm(remains.get('validation_rms_um'), 4)} = "
        f"{remains.get('ratio_to_noise_floor') or float('nan'):.2f}× the noise floor "
        f"({fmt_nm(remains.get('noise_floor_um'), 3)})" + (f"; error: {result['error']}" if result.get("error") else "")
    )
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--bench", default="default")
    ap.add_argument("--axis", default="y", choices=["y", "z"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None, help="also write the job's result here")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    os.environ.setdefault("EVCBENCH_ENGINE", "inline")
    result = run(args.bench, args.axis, args.seed)
    print(table(result))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1, default=str)


if __name__ == "__main__":
    main()
