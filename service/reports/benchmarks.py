"""Write docs/benchmarks.md: run each benchmark the way a user does (``evcbench bench <name> --json``,
service/perf/) and put its figures beside the command that produced them.

    python -m service.reports.benchmarks                          # every benchmark (tens of minutes)
    python -m service.reports.benchmarks --only emulator,auth     # these; the others keep their figures

Each run's JSON answer is kept in docs/benchmarks.json with the date, the wall time and the machine
(cores, load before the run), so a partial regeneration keeps the other benchmarks' last figures and
the page says, per benchmark, when and where it was measured. Figures from different runs (or
machines) are not comparable: a benchmark compares its own figures side by side within one run.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MARKDOWN = ROOT / "docs" / "benchmarks.md"
RESULTS = ROOT / "docs" / "benchmarks.json"

#: What each benchmark measures, in one line (the modules' docstrings say it at length).
WHAT: dict[str, str] = {
    "emulator": "the emulator's speed against real time at 20 kHz (drivers/emulated/benchmark.py)",
    "identification": "exact least squares against the paper's PSO on the same dynamic-PI data",
    "discovery": "one full diagnosis (every candidate fitted and validated) of a 4-frequency two-axis sweep",
    "control": "the controller's cost per sample against the 50 µs period; the closed loop's real-time factor",
    "service": "request latency and the real-time job's overruns under 50 requests/s (`--duration`, default 60 s)",
    "auth": "p50 of a status read with the token check against without it",
    "safety": "stop → 0 V idle and under load (a sweep, 4 downloads, a 50 MB import); faults; the watchdog",
    "engine_death": "a killed and a hung bench engine: death → 0 V and the restart, with and without the output stage's watchdog",
    "batch": "batch diagnosis of 64 datasets on Dask, 1 against 2 workers (docs/lab-batch.md)",
}
#: The order of the page, and of a full run: the cheap ones first; a benchmark `evcbench bench` knows
#: beyond these comes after them (this page runs the CLI as a user would and imports no benchmark).
ORDER = ("emulator", "auth", "control", "identification", "discovery", "service", "safety", "engine_death", "batch")
#: A list longer than this is shown as its length and ends, not in full.
LIST_SHOWN = 8


def command(name: str) -> list[str]:
    """The command a user types: the virtualenv's ``evcbench`` (else this Python's CLI module)."""
    script = Path(sys.executable).with_name("evcbench")
    prefix = [str(script)] if script.exists() else [sys.executable, "-m", "service.frontends.cli"]
    return [*prefix, "bench", name, "--json"]


def known_benchmarks() -> list[str]:
    """Every benchmark ``evcbench bench`` knows (its refusal of an unknown name lists them), ORDER's first."""
    refusal = subprocess.run([*command("?")[:-2], "?"], cwd=ROOT, capture_output=True, text=True).stderr
    known = refusal.rpartition("known: ")[2].strip().split(", ") if "known: " in refusal else []
    return [n for n in ORDER if n in known or not known] + sorted(n for n in known if n not in ORDER)


def run_one(name: str, run: str) -> dict:
    """Run one benchmark in its own process; its answer and how the run went (``run``: when this
    regeneration started, which the page groups benchmarks by)."""
    load = os.getloadavg()[0]
    started, clock = dt.datetime.now(dt.UTC), time.monotonic()
    done = subprocess.run(command(name), cwd=ROOT, capture_output=True, text=True)
    took = time.monotonic() - clock
    if done.returncode != 0:
        raise RuntimeError(f"evcbench bench {name} --json exited with {done.returncode}:\n{done.stderr[-2000:]}")
    return {
        "run": run,
        "result": json.loads(done.stdout.strip().splitlines()[-1]),
        "measured_at": started.strftime("%Y-%m-%d %H:%M UTC"),
        "wall_s": round(took, 1),
        "machine": {
            "cores": os.cpu_count(),
            "load_1min_before": load,
            "load_1min_after": os.getloadavg()[0],
            "python": platform.python_version(),
        },
    }


def _value(value) -> str:
    if isinstance(value, bool) or value is None:
        return json.dumps(value)
    if isinstance(value, float):
        return f"{value:.0f}" if value.is_integer() and abs(value) < 1e9 else f"{value:.4g}"
    if isinstance(value, list):
        if len(value) > LIST_SHOWN:
            return f"{len(value)} values: {_value(value[0])} … {_value(value[-1])}"
        return "[" + ", ".join(_value(v) for v in value) + "]"
    return str(value).replace("|", "\\|").replace("\n", " ")


def _rows(result: dict, prefix: str = "") -> list[tuple[str, str]]:
    """The answer's figures as (dotted key, value) rows, nested objects flattened."""
    rows: list[tuple[str, str]] = []
    for key, value in result.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            rows.extend(_rows(value, f"{path}."))
        else:
            rows.append((path, _value(value)))
    return rows


def render(results: dict[str, dict], order: list[str]) -> str:
    """docs/benchmarks.md from the stored answers, a section per benchmark in ``order``."""
    lines = [
        "# Benchmarks",
        "",
        "Generated by `.venv/bin/python -m service.reports.benchmarks` (do not edit by hand). Each section is",
        "one benchmark: the command that measured it, when and on what, and every figure of its JSON answer.",
        "A benchmark measures its figures side by side in one run: compare figures within a section, not",
        "across sections or dates. A load average above the cores' number means other work shared the",
        "machine during the run (on a shared 2-core machine, latencies then grow by several times).",
        "",
        "Regenerate every benchmark (tens of minutes), or some of them (the others keep their last figures):",
        "",
        "```sh",
        ".venv/bin/python -m service.reports.benchmarks",
        ".venv/bin/python -m service.reports.benchmarks --only emulator,auth,control",
        "```",
        "",
    ]
    runs: dict[str, list[str]] = {}
    for name in order:
        if name in results:
            runs.setdefault(results[name].get("run", results[name]["measured_at"]), []).append(name)
    missing = [name for name in order if name not in results]
    lines.append(
        f"The figures below come from {len(runs)} regeneration{'s' if len(runs) > 1 else ''} of this page: "
        + "; ".join(f"{run}: {', '.join(names)}" for run, names in sorted(runs.items()))
        + (f". Not measured yet: {', '.join(missing)}" if missing else "")
        + "."
    )
    lines.append("")
    for name in order:
        what = WHAT.get(name, "") or f"see `evcbench bench {name}`'s module in service/perf/"
        lines += [
            f"## {name}",
            "",
            f"{what[:1].upper()}{what[1:]}.",
            "",
            "```sh",
            f".venv/bin/evcbench bench {name} --json",
        ]
        lines += ["```", ""]
        run = results.get(name)
        if run is None:
            lines += ["Not measured yet: run the command above, or regenerate this page with it.", ""]
            continue
        m = run["machine"]
        load = f", load average {m['load_1min_before']:.1f} before it" if "load_1min_before" in m else ""
        load += f" and {m['load_1min_after']:.1f} after" if "load_1min_after" in m else ""
        lines += [
            f"Measured {run['measured_at']} in {run['wall_s']:g} s ({m['cores']} cores{load}; Python {m['python']}).",
            "",
            "| figure | value |",
            "|---|---|",
        ]
        lines += [f"| `{key}` | {value} |" for key, value in _rows(run["result"])]
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", help="comma-separated benchmarks (default: every one evcbench bench knows)")
    parser.add_argument("--render", action="store_true", help="rewrite the page from docs/benchmarks.json only")
    args = parser.parse_args(argv)
    known = known_benchmarks()
    names = known if not args.only else [n.strip() for n in args.only.split(",") if n.strip()]
    unknown = sorted(set(names) - set(known))
    if unknown:
        parser.error(f"unknown benchmark(s) {', '.join(unknown)}; known: {', '.join(known)}")
    results = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    order = known + [name for name in results if name not in known]
    run = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    fresh = [] if args.render else names
    for name in fresh:
        print(f"evcbench bench {name} --json …", file=sys.stderr, flush=True)
        results[name] = run_one(name, run)
        RESULTS.write_text(json.dumps(results, indent=1) + "\n")  # a later failure keeps what ran
        MARKDOWN.write_text(render(results, order))
        print(f"  {results[name]['wall_s']:g} s", file=sys.stderr, flush=True)
    MARKDOWN.write_text(render(results, order))
    print(f"wrote {MARKDOWN.relative_to(ROOT)} ({', '.join(fresh) or 'rendered only'})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
