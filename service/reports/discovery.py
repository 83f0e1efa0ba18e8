"""Reproduce docs/discovery.md's run: ``python -m service.reports.discovery [--bench default]
[--axis y] [--figure docs/img/discovery_history.png] [--continue-past-ambiguity]``. Prints the steps
as Markdown. Like the discover job without experiments, the loop stops at an ambiguity and names
the sweep that separates the pair, unless ``--continue-past-ambiguity``."""

from __future__ import annotations

import argparse
import warnings

from service.lab.emulated import sweep_records
from service.science.discovery.loop import discovery_run, history_figure, markdown, stops_at_ambiguity


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--bench", default="default")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--axis", default="y", choices=["y", "z"])
    ap.add_argument("--figure", default="docs/img/discovery_history.png")
    ap.add_argument(
        "--continue-past-ambiguity",
        action="store_true",
        help="at an ambiguity, add the leading claimed effect and go on (else stop and name the sweep)",
    )
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    record = sweep_records(args.bench, args.seed)[args.axis]
    steps = discovery_run([record], continue_past_ambiguity=args.continue_past_ambiguity)
    history_figure(steps, args.figure, f"Discovery on the {args.bench} bench, axis {args.axis.upper()}")
    print(markdown(steps))
    need = stops_at_ambiguity(steps[-1]["diagnosis"], args.continue_past_ambiguity)
    if need is not None:
        print(
            f"**Stopped at step {len(steps) - 1}: an ambiguity.** {need['reason']}. The sweep that separates "
            f"them: `POST /api/sweeps {need['experiment']}` (or run with --continue-past-ambiguity).\n"
        )
    print("| frequency | validation RMS (nm) | noise floor (nm) | ratio |\n|---|---|---|---|")
    for b in steps[-1]["per_block"]:
        print(
            f"| {b['frequency_hz']:g} Hz | {b['validation_rms_um'] * 1e3:.2f} | {b['noise_floor_um'] * 1e3:.2f} | "
            f"{b['validation_rms_um'] / b['noise_floor_um']:.1f} |"
        )


if __name__ == "__main__":
    main()
