"""What the REST verbs of the CLI print: a discover job's result in words, the progress bar of a long
job on stderr, and the figures' formats (errors and noise in nm, like every page and text)."""

from __future__ import annotations

import json
import sys

from service.render.text import step_change
from service.science.data.units import fmt_nm


def discovery_text(result: dict) -> str:
    """A discover job's result in words: final model, effects found with their parameters, what remains."""
    lines = [
        f"final model {result['final_model_id']}: {' + '.join(result['effects'] or [])} (stopped: {result['stopped']})"
    ]
    for step in result["steps"]:
        change = step_change(step) or (
            f"+data {step['experiment_dataset_id']}" if step.get("experiment_dataset_id") else ""
        )
        same = step.get("like_for_like_rms_um")
        lines.append(
            f"  step {step['step']} {change:<18} {step['model_id']}  "
            f"held-out {nm_text(step['validation_rms_um'])}  noise floor {nm_text(step['noise_floor_um'])}"
            + (
                f"  like for like {nm_text(same)} (that fit on the original data {nm_text(step.get('original_data_rms_um'))})"
                if same is not None and result.get("experiments")
                else ""
            )
        )
        lines += [f"    tried next: {r['text']} (model {r['model_id']})" for r in step.get("not_kept", [])]
    if result.get("experiments"):
        lines.append(
            "  like for like: every step refitted and scored on all of "
            + ", ".join(result.get("like_for_like_datasets") or [])
            + "; original data: on "
            + ", ".join(result.get("original_datasets") or [])
        )
    for ran in result["experiments"]:
        lines.append(
            f"experiment for {' / '.join(ran['effects'])}: dataset {ran['dataset_id']} "
            + (
                "(recorded before for this model, not run again), "
                if ran.get("recorded_before")
                else f"(sweep job {ran['sweep_job_id']}), "
            )
            + ("resolved" if ran.get("resolved") else "not resolved by it")
            + (f"; cut to the bench's limits: {'; '.join(ran['cut_to_bench'])}" if ran.get("cut_to_bench") else "")
        )
    for skipped in [x for x in result.get("suggested_experiments", []) if x.get("skipped")]:
        lines.append(f"experiment for {' / '.join(skipped['effects'])} skipped: {skipped['not_run_because']}")
    for found in result["effects_found"]:
        figures = ", ".join(f"{k} {v:.4g}" for k, v in found["parameters"].items())
        lines.append(
            (
                f"added {found['effect']} as model capacity, not physics"
                if found["kind"] == "capacity"
                else f"found {found['effect']}"
            )
            + (f": {figures}" if figures else "")
            + f"\n  evidence: {found['evidence']}"
        )
    remains = result.get("remains") or {}
    if remains:
        lines.append(
            f"remains: held-out {nm_text(remains['validation_rms_um'])} = {remains['ratio_to_noise_floor']:.2f}× "
            f"the noise floor ({nm_text(remains['noise_floor_um'])}): {remains.get('answer_text') or ''} "
            f"{remains['verdict_text']}"
        )
    need = result.get("needed_experiment")
    if need and not need.get("experiment"):  # one this bench cannot run, even cut to its limits
        lines.append(
            f"an experiment would help ({need['reason']}), but this bench cannot run it: {need.get('not_runnable_here')}"
        )
    elif need:
        lines.append(
            f"an experiment would help ({need['reason']}): POST /api/sweeps {json.dumps(need['experiment'])}"
            " — or run again with --allow-experiments"
            + (
                ""
                if result["stopped"] != "needs_experiment"
                else ", or with --continue-past-ambiguity to add the leading effect and go on"
            )
        )
    return "\n".join(lines)


class ProgressBar:
    """A one-line text bar on stderr, redrawn from the job's SSE progress events; into a pipe or a log
    (not a terminal) a line per new message and the end state instead of a carriage-return redraw."""

    def __init__(self, width: int = 30, stream=None):
        self.width, self.stream, self._last = width, stream or sys.stderr, None
        self.redraw = bool(getattr(self.stream, "isatty", lambda: False)())

    def __call__(self, job: dict) -> None:
        ended = job["state"] in ("succeeded", "failed", "cancelled")
        percent = f"{job['progress'] * 100:5.1f} %"
        if self.redraw:
            filled = int(round(job["progress"] * self.width))
            line = (
                f"\r[{'#' * filled}{'-' * (self.width - filled)}] {percent} "
                f"{job['state']}: {(job.get('message') or '')[:50]:<50}"
            )
            key = line
        else:  # a new line only when the state or the message changes; the percentage it was reached at
            key = (job["state"], job.get("message") or "")
            line = f"{percent} {job['state']}: {job.get('message') or ''}\n"
        if key != self._last and (self.redraw or ended or job.get("message")):
            self.stream.write(line)
            self.stream.flush()
            self._last = key
        if ended and self.redraw:
            self.stream.write("\n")
            self.stream.flush()


def num_text(value, fmt: str = ".4f") -> str:
    return "-" if value is None else format(value, fmt)


def nm_text(value_um) -> str:
    """An error or noise figure (µm) as the CLI prints it: nm, like every page and text."""
    return "-" if value_um is None else fmt_nm(value_um, 4)
