"""The paper's two tracking cases (Fig. 14–15) on ``paper_measured``, the device as the paper measured it,
over the REST path, and docs/tracking.md's section on them.

    python -m service.reports.tracking_measured [--seed 1] [--cycles 50]

As a REST user would (service/reports/rest_path.py, answered in process by the routers' use cases):
``POST /api/sweeps`` (1/10/50/100 Hz, 0–120 V, 5 cycles, one axis at a time), then per axis

- the paper's controller structure: ``POST /api/models`` with ``"model": "dynamic_pi"`` (the paper's
  dynamic PI, identified on that sweep as the paper did), its inverse as feedforward and the PID the
  service tunes (``"pid": "auto"``); its per-sample inverse misses at 100 Hz, so the service solves
  its drive period by period (service.science.control.periodic_inverse); the same structure runs
  with the static PI and with the composite feedforward too;
- the product's best controller: the composite feedforward of docs/tracking.md (hysteresis with
  ``rest_path.EFFECTS``, refitted on the span sweeps the API offers per case), PID (auto) and ILC.

The maximum errors (µm, over the last 5 steady periods) stand beside the paper's (service/science/paper.py).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from service.reports.doc_sections import write_section
from service.reports.rest_path import FIRST_SWEEP, UseCases, _result, first_models, identify_for, run_row
from service.runtime.settings import Settings
from service.science import paper

ROOT = Path(__file__).resolve().parents[2]
BENCH = "paper_measured"
CASES = {case: spec["body"] for case, spec in paper.TRACKING_CASES.items()}
#: the report's rows: (feedforward, controller body). "dynamic_pi" is the paper's model (its drive solved
#: period by period; a 422 row if even that missed), "static_pi" the paper's structure with the static
#: PI, "composite" the product's feedforward (docs/tracking.md)
ROWS = {
    "paper's structure: dynamic PI⁻¹ FF + PID (auto)": ("dynamic_pi", {"pid": "auto"}),
    "paper's structure with the static PI: static PI⁻¹ FF + PID (auto)": ("static_pi", {"pid": "auto"}),
    "composite FF + PID (auto)": ("composite", {"pid": "auto"}),
    "product's best: composite FF + PID (auto) + ILC": ("composite", {"pid": "auto", "ilc": True}),
}
PI_MODELS = ("dynamic_pi", "static_pi")
SECTION = "paper_measured tracking"
COMMAND = "python -m service.reports.tracking_measured"


def pi_models(post) -> dict[str, dict[str, str]]:
    """model kind → axis → model id, each of ``PI_MODELS`` identified on the identification sweep
    (``FIRST_SWEEP``), as the paper identified its models."""
    dataset_id = _result(post("/api/sweeps", FIRST_SWEEP))["dataset_id"]
    return {
        kind: {
            ax: _result(post("/api/models", {"axis": ax, "datasets": [dataset_id], "model": kind}))["model_id"]
            for ax in ("y", "z")
        }
        for kind in PI_MODELS
    }


def measure(seed: int = 1, cycles: int = 50, data_dir: Path | None = None) -> dict:
    """case → row name → the trajectory job's result (or ``{"refused"|"tripped": …}``), on a fresh
    ``paper_measured`` service with ``seed``."""
    with tempfile.TemporaryDirectory(prefix="evc-tracking-measured-") as tmp:
        uc = UseCases(Settings(data_dir=Path(data_dir or tmp), bench=BENCH, seed=seed, engine="inline"))
        try:
            ff = pi_models(uc.post)
            first = first_models(uc.post)
            out = {}
            for case, body in CASES.items():
                body = {**body, "cycles": cycles}
                ff["composite"] = identify_for(uc.post, body, first)
                out[case] = {name: run_row(uc.post, body, ff[kind], ctl) for name, (kind, ctl) in ROWS.items()}
        finally:
            uc.close()
    return out


def _cell(row: dict, key: str) -> str:
    value = row.get(key)
    return "—" if value is None else f"{value:.3f}"


def _note(row: dict) -> str:
    if row.get("refused"):
        return f"422 on `{row['refused']['field']}`: {row['refused']['detail']}"
    return row.get("tripped") or ""


def section(results: dict, seed: int, cycles: int) -> str:
    """docs/tracking.md's section on ``paper_measured`` (``SECTION``)."""
    lines = [
        "## The paper's cases on the device as the paper measured it (`paper_measured`)",
        "",
        f"Regenerate (writes this section only): `.venv/bin/python -m service.reports.tracking_measured --seed {seed} "
        f"--cycles {cycles}`.",
        "",
        "`paper_measured` (fixtures/benches/paper_measured.toml) is the device fitted to the paper's Table 6, "
        "its first modes where the measured 100 Hz cells put them (docs/calibration.md, docs/reproduction.md). "
        "Over the REST path as above: the identification sweep, then per axis the paper's controller "
        '(`POST /api/models` with `"model": "dynamic_pi"`, its inverse as feedforward, `"pid": "auto"`). The '
        "dynamic PI's per-sample inverse misses the 100 Hz ellipse (its rate weights switch with the signs of "
        "u̇ and ü), so the service solves its drive period by period on the model's own prediction "
        "(service/science/control/periodic_inverse.py). The same structure also runs with the static PI "
        '(`"model": "static_pi"`) and with the composite feedforward of the rows above; '
        'the product\'s best adds ILC (`"pid": "auto"`, `"ilc": true`). '
        f"Seed {seed}, {cycles} periods at 100 Hz; maximum errors over the last 5 steady periods.",
        "",
        "| case | controller | max error Y (µm) | max error Z (µm) | RMS (nm) | relative error (%) | note |",
        "|---|---|---|---|---|---|---|",
    ]
    for case, rows in results.items():
        spec = paper.TRACKING_CASES[case]
        lines.append(
            f"| {case} | **paper** (dynamic PI⁻¹ FF + PID, Fig. 15) | {spec['max_error_um']['y']} | "
            f"{spec['max_error_um']['z']} | — | {paper.paper_relative_error(case)} | |"
        )
        for name, row in rows.items():
            rms_nm = row.get("rms_error_um")
            lines.append(
                f"| {case} | {name} | {_cell(row, 'max_error_y_um')} | {_cell(row, 'max_error_z_um')} | "
                f"{'—' if rms_nm is None else f'{1e3 * rms_nm:.1f}'} | {_cell(row, 'relative_error_pct')} | "
                f"{_note(row)} |"
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog=COMMAND, description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cycles", type=int, default=50)
    ap.add_argument("--out", default=str(ROOT / "docs" / "tracking.md"))
    args = ap.parse_args(argv)
    results = measure(args.seed, args.cycles)
    block = section(results, args.seed, args.cycles)
    print(block)
    write_section(Path(args.out), SECTION, block)
    return results


if __name__ == "__main__":  # pragma: no cover
    main()
