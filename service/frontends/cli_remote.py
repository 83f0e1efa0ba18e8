"""CLI verbs that talk to a running service over REST: sweep, import, identify, compare, discover,
jobs, datasets, models (with rename, tag, annotate and delete). Long jobs show a text progress bar on stderr; results go to stdout."""

from __future__ import annotations

import argparse
import json
import os
import sys

import httpx

from service.frontends.cli_text import ProgressBar, discovery_text, nm_text, num_text
from service.frontends.client import DEFAULT_URL, ApiError, Client, StopNotDelivered


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register the remote verbs on the ``evcbench`` sub-parser."""
    _add_acquisition(sub)
    _add_modelling(sub)
    _add_records(sub)


def _remote(sub: argparse._SubParsersAction, name: str, help_text: str, func) -> argparse.ArgumentParser:
    """A remote verb's parser with the options every one takes: --url, --token, --json."""
    p = sub.add_parser(name, help=help_text)
    p.add_argument(
        "--url",
        default=os.environ.get("EVCBENCH_URL", DEFAULT_URL),
        help=f"service address (default {DEFAULT_URL}, env EVCBENCH_URL)",
    )
    p.add_argument(
        "--token",
        help="API token (default: env EVCBENCH_TOKEN, or for a local service "
        "<data dir>/admin.token, the data dir from EVCBENCH_DATA_DIR or ./var)",
    )
    p.add_argument("--json", action="store_true", help="print the raw JSON answer")
    p.set_defaults(func=lambda args: _guarded(func, args))
    return p


def _add_acquisition(sub: argparse._SubParsersAction) -> None:
    """``sweep`` and ``import``: the verbs that make a dataset."""
    p = _remote(sub, "sweep", "run a characterisation sweep on the bench", _sweep)
    p.add_argument("--axes", default="y", help="comma-separated axes: y, z or y,z (default y)")
    p.add_argument("--waveform", default="sine", help="sine | step | chirp | multisine (default sine)")
    p.add_argument("--frequencies", default="1,10,50,100", help="comma-separated hertz (sine, multisine)")
    p.add_argument("--cycles", type=int, default=5, help="cycles per frequency (default 5)")
    p.add_argument("--v-min", type=float, default=0.0, help="lowest actuator volts (default 0)")
    p.add_argument("--v-max", type=float, default=120.0, help="highest actuator volts (default 120)")
    p.add_argument("--settle-s", type=float, default=0.2, help="rest at v_min between blocks (default 0.2 s)")
    p.add_argument("--sample-rate-hz", type=float, default=20000.0, help="DAQ rate, a divisor of 100 MHz")
    p.add_argument("--separate", action="store_true", help="run the axes one after the other")
    p.add_argument("--levels", help="step: comma-separated levels in volts (default v_max)")
    p.add_argument("--hold-s", type=float, default=2.0, help="step: hold time per level (default 2 s)")
    p.add_argument("--f-start-hz", type=float, default=1.0, help="chirp: start frequency")
    p.add_argument("--f-stop-hz", type=float, default=100.0, help="chirp: stop frequency")
    p.add_argument("--duration-s", type=float, default=10.0, help="chirp: duration")
    p.add_argument("--name", help="dataset name")
    p.add_argument("--wait", action="store_true", help="follow the job to its end with a progress bar")

    p = _remote(sub, "import", "import a CSV or table file as a dataset", _import)
    p.add_argument(
        "file",
        help="CSV with header t,u_y,x_y,u_z,x_z (s, V at the actuator, µm; units written in the names are converted: 'Time [ms]', x_y_nm) or a headerless table with --columns",
    )
    p.add_argument("--columns", help='JSON column mapping for headerless files, e.g. \'{"u":0,"x":4}\'')
    p.add_argument("--sample-rate-hz", type=float, help="needed when the file has no t column")
    p.add_argument("--axis", default="y", help="axis of a single-axis (u, x) file (default y)")
    p.add_argument("--delimiter", help="comma | tab | semicolon | whitespace (default: guess)")
    p.add_argument("--name", help="dataset name (default: the file name)")


def _add_modelling(sub: argparse._SubParsersAction) -> None:
    """``identify``, ``compare`` and ``discover``: the verbs that fit and judge models."""
    p = _remote(sub, "identify", "identify a hysteresis model from datasets", _identify)
    p.add_argument("--axis", default="y", help="y or z (default y)")
    p.add_argument("--datasets", required=True, help="comma-separated dataset ids")
    p.add_argument("--model", default="static_pi", help="static_pi | dynamic_pi | grpi (default static_pi)")
    p.add_argument("--effects", default="hysteresis", help="comma-separated effects (default hysteresis)")
    p.add_argument("--n-operators", type=int, default=10, help="play operators (default 10)")
    p.add_argument("--no-wait", action="store_true", help="print the job id and return")

    p = _remote(sub, "compare", "compare a model with a dataset: RMS, max and fit %%, per block", _compare)
    p.add_argument("model_id")
    p.add_argument("--dataset", required=True, help="dataset id")

    p = _remote(
        sub,
        "discover",
        "run the discovery loop from a model: diagnose, add the missing effect, refit, "
        "repeat; then capacity down to the noise floor",
        _discover,
    )
    p.add_argument("model_id")
    p.add_argument(
        "--allow-experiments",
        action="store_true",
        help="run the sweep the loop needs on the bench when it is free (else it stops and names it)",
    )
    p.add_argument(
        "--continue-past-ambiguity",
        action="store_true",
        help="at an ambiguity it may not test, add the leading claimed effect and go on (else it stops "
        "there and names the sweep that would tell the two apart)",
    )
    p.add_argument(
        "--max-steps",
        type=int,
        default=None,
        help="model steps at most, the model's own diagnosis the first; a refit on an experiment's data "
        "does not count (1–16; default: the service's, 12)",
    )
    p.add_argument(
        "--max-experiments",
        type=int,
        default=None,
        help="experiments run at most with --allow-experiments (0–10, default 3)",
    )


def _add_records(sub: argparse._SubParsersAction) -> None:
    """``jobs``, ``stop``, ``reset``, ``datasets`` and ``models``."""
    p = _remote(sub, "jobs", "list jobs, show one, follow it, or cancel it", _jobs)
    p.add_argument("job_id", nargs="?")
    p.add_argument("--cancel", action="store_true", help="cancel the job (a sweep keeps its partial data)")
    p.add_argument("--watch", action="store_true", help="follow the job with a progress bar")

    _remote(sub, "stop", "emergency stop: every output to 0 V, the bench job and its queue cancelled", _stop)
    _remote(sub, "reset", "clear latched amplifier faults and the watchdog's trip (bench idle, outputs at 0 V)", _reset)

    p = _remote(sub, "datasets", "list datasets, show one, or rename, tag, annotate or delete it", _datasets)
    p.add_argument("dataset_id", nargs="?")
    _tidy_options(p, "the models fitted on it")

    p = _remote(sub, "models", "list models, show one, or rename, tag, annotate or delete it", _models)
    p.add_argument("model_id", nargs="?")
    p.add_argument("--report", metavar="FILE", help="write the model's HTML report to FILE (print it for a PDF)")
    _tidy_options(p, "every model refined from it")


def _tidy_options(p: argparse.ArgumentParser, dependents: str) -> None:
    p.add_argument("--rename", metavar="NAME", help="set its name")
    p.add_argument("--tags", help="comma-separated tags (replace its tags; '' clears them)")
    p.add_argument("--notes", help="set its notes ('' clears them)")
    p.add_argument("--delete", action="store_true", help=f"delete it (refused while {dependents} exist)")
    p.add_argument("--cascade", action="store_true", help=f"with --delete: also delete {dependents}")


# ---------------------------------------------------------------------- verbs
def _sweep(api: Client, args) -> int:
    plan = {
        "axes": _list(args.axes),
        "waveform": args.waveform,
        "cycles": args.cycles,
        "v_min": args.v_min,
        "v_max": args.v_max,
        "settle_s": args.settle_s,
        "sample_rate_hz": args.sample_rate_hz,
        "together": not args.separate,
        "hold_s": args.hold_s,
        "f_start_hz": args.f_start_hz,
        "f_stop_hz": args.f_stop_hz,
        "duration_s": args.duration_s,
        "name": args.name,
    }
    if args.waveform in ("sine", "multisine"):
        plan["frequencies_hz"] = [float(f) for f in _list(args.frequencies)]
    if args.levels:
        plan["levels_v"] = [float(v) for v in _list(args.levels)]
    started = api.start_sweep(**plan)
    print(
        f"sweep job {started['job_id']}: {started['samples']} samples, {started['duration_s']:.2f} s", file=sys.stderr
    )
    if not args.wait:
        return _emit(args, started, f"job {started['job_id']} {started['state']}")
    job = api.wait(started["job_id"], ProgressBar())
    result = job.get("result") or {}
    text = f"dataset {result.get('dataset_id')}" + (" (partial)" if result.get("partial") else "")
    return _finish(args, job, text)


def _import(api: Client, args) -> int:
    row = api.import_dataset(
        args.file,
        name=args.name,
        axis=args.axis,
        columns=args.columns,
        sample_rate_hz=args.sample_rate_hz,
        delimiter=args.delimiter,
    )
    notes = "".join(f"\n  note: {note}" for note in row.get("import_notes") or [])
    return _emit(
        args,
        row,
        f"dataset {row['id']}: axes {','.join(row['axes'])}, {row['samples']} samples "
        f"at {row['sample_rate_hz']:g} Hz{notes}",
    )


def _identify(api: Client, args) -> int:
    started = api.start_identify(args.axis, _list(args.datasets), args.model, _list(args.effects), args.n_operators)
    if args.no_wait:
        return _emit(args, started, f"job {started['job_id']} {started['state']}")
    job = api.wait(started["job_id"], ProgressBar())
    if job["state"] != "succeeded":
        return _finish(args, job, "")
    model = api.model(job["result"]["model_id"])
    m = model["metrics"]
    return _emit(
        args,
        model,
        f"model {model['id']} ({model['kind']}, axis {model['axis']}): train RMS "
        f"{nm_text(m['train_rms_um'])}, held-out RMS {nm_text(m['validation_rms_um'])}",
    )


def _compare(api: Client, args) -> int:
    result = api.compare(args.model_id, args.dataset, arrays=False)
    if args.json:
        print(json.dumps(result["metrics"], indent=2))
        return 0
    m = result["metrics"]
    print(
        f"model {args.model_id} vs dataset {args.dataset} (axis {result['axis']}, "
        f"{'used in the fit' if result['used_in_fit'] else 'not used in the fit'})"
    )
    print(
        f"{'block':>5} {'kind':>9} {'f_hz':>8} {'train_rms_um':>13} {'heldout_rms_um':>15} "
        f"{'heldout_max_um':>15} {'heldout_fit_pct':>16}"
    )
    for b in m["per_block"]:
        print(
            f"{b['index']:>5} {b['kind']:>9} {num_text(b['frequency_hz'], '.4g'):>8} {num_text(b['train']['rms_um']):>13} "
            f"{num_text(b['validation']['rms_um']):>15} {num_text(b['validation']['max_abs_um']):>15} "
            f"{num_text(b['validation']['fit_pct'], '.2f'):>16}"
        )
    o = m["overall"]
    print(
        f"overall: RMS {nm_text(o['rms_um'])}, max {nm_text(o['max_abs_um'])}, fit {num_text(o['fit_pct'], '.2f')} %; "
        f"mean held-out RMS {nm_text(m['validation_rms_um'])}"
    )
    return 0


def _discover(api: Client, args) -> int:
    bar = ProgressBar()

    def progress(job: dict) -> None:  # each step's line as it is stored, then the bar
        steps = (job.get("result") or {}).get("steps") or []
        for step in steps[len(seen) :]:
            print(
                f"\rstep {step['step']}: {' + '.join(step['effects']):<50} {step['model_id']}  held-out "
                f"{nm_text(step['validation_rms_um'])}, noise floor {nm_text(step['noise_floor_um'])}",
                file=sys.stderr,
            )
        seen[:] = steps
        bar(job)

    seen: list = []
    job = api.discover(
        args.model_id,
        args.allow_experiments,
        args.max_steps,
        on_progress=progress,
        continue_past_ambiguity=args.continue_past_ambiguity,
        max_experiments=args.max_experiments,
    )
    return _finish(args, job, discovery_text(job["result"]) if job.get("result") else "")


def _jobs(api: Client, args) -> int:
    if not args.job_id:
        rows = api.jobs()
        if args.json:
            print(json.dumps(rows, indent=2))
        for j in rows if not args.json else []:
            print(f"{j['id']}  {j['kind']:<9} {j['state']:<10} {j['progress'] * 100:5.1f} %  {j['message'] or ''}")
        return 0
    if args.cancel:
        job = api.cancel(args.job_id)
        return _emit(args, job, f"job {job['id']}: {job['state']} ({job['message']})")
    if args.watch:
        return _finish(args, api.wait(args.job_id, ProgressBar()), "")
    job = api.job(args.job_id)
    return _emit(
        args,
        job,
        f"job {job['id']} {job['kind']}: {job['state']} {job['progress'] * 100:.0f} % "
        f"{job['message'] or ''}\nresult: {json.dumps(job['result'])}\nerror: {job['error']}",
    )


def _stop(api: Client, args) -> int:
    out = api.stop_bench()
    volts = ", ".join(f"{axis} {0.0 if abs(v) < 0.005 else v:.2f} V" for axis, v in out["output_v"].items())
    volts = volts or "not read (no bench engine)"
    zero = out.get("zero_after_request_ms")
    queued, running = out["cancelled_queued_job_ids"], out["cancelled_job_id"]
    by_engine = queued is None  # the stop port: the service cancels the jobs after it
    if by_engine:
        queued_text = "the service cancels any (the bench runs none until it has)"
    else:
        queued_text = ", ".join(queued) + " cancelled" if queued else "none"
    running_text = "none" if not running else f"{running} {'(the service cancels it)' if by_engine else 'cancelled'}"
    lines = [
        f"stopped on the {out.get('door', 'service route')}"
        + (f", 0 V {zero:.1f} ms after the stop reached the bench" if zero is not None else ""),
        f"outputs: {volts}",
        f"running job: {running_text}",
        f"queued bench jobs: {queued_text}",
    ]
    if out.get("engine_note"):
        lines.append(f"engine: {out['engine_note']}")
    if out.get("stop_port_refusal"):
        lines.append(f"(the stop port was not used: {out['stop_port_refusal']})")
    return _emit(args, out, "\n".join(lines))


def _reset(api: Client, args) -> int:
    out = api.reset_bench()
    lines = [f"cleared: {c}" for c in out["cleared"]] or ["nothing was latched"]
    if out["remaining"]:
        lines.append(f"still faulted (a reset cannot mend it): {out['remaining']}")
    _emit(args, out, "\n".join(lines))
    return 1 if out["remaining"] else 0


def _tidy(args, label, delete, record_id: str) -> tuple[dict, str] | None:
    """Apply --rename/--tags/--notes or --delete to ``record_id``; (answer, words) or None if none was given."""
    if args.delete:
        gone = delete(record_id, cascade=args.cascade)
        return gone, (
            f"deleted datasets {', '.join(gone['datasets']) or 'none'}, models "
            f"{', '.join(gone['models']) or 'none'}; freed {gone['freed_bytes']} bytes"
        )
    labels = {}
    if args.rename is not None:
        labels["name"] = args.rename
    if args.tags is not None:
        labels["tags"] = _list(args.tags)
    if args.notes is not None:
        labels["notes"] = args.notes or None
    if not labels:
        return None
    row = label(record_id, **labels)
    return row, f"{row['id']}: name {row['name']!r}, tags {', '.join(row['tags']) or '-'}, notes {row['notes']!r}"


def _datasets(api: Client, args) -> int:
    done = args.dataset_id and _tidy(args, api.label_dataset, api.delete_dataset, args.dataset_id)
    if done:
        return _emit(args, *done)
    if args.dataset_id:
        row = api.dataset(args.dataset_id)
        return _emit(args, row, json.dumps({k: v for k, v in row.items() if k != "config"}, indent=2))
    rows = api.datasets()
    return _emit(
        args,
        rows,
        "\n".join(
            f"{r['id']}  {r['source']:<6} {','.join(r['axes']):<4} {r['samples']:>9} samples "
            f"{r['sample_rate_hz']:>8g} Hz {'partial ' if r['partial'] else ''}{r['name']}"
            for r in rows
        ),
    )


def _models(api: Client, args) -> int:
    if args.model_id and args.report:
        html = api.model_report(args.model_id)
        with open(args.report, "w", encoding="utf-8") as out:
            out.write(html)
        return _emit(
            args,
            {"model_id": args.model_id, "report": args.report, "bytes": len(html.encode())},
            f"report of {args.model_id}: {args.report} ({len(html.encode()) / 1024:.0f} kB)",
        )
    done = args.model_id and _tidy(args, api.label_model, api.delete_model, args.model_id)
    if done:
        return _emit(args, *done)
    if args.model_id:
        row = api.model(args.model_id)
        return _emit(args, row, json.dumps(row, indent=2))
    rows = api.models()
    return _emit(
        args,
        rows,
        "\n".join(
            f"{r['id']}  {r['kind']:<10} axis {r['axis']}  held-out RMS {nm_text(r['metrics']['validation_rms_um'])}  "
            f"datasets {','.join(r['datasets'])}"
            for r in rows
        ),
    )


# ---------------------------------------------------------------------- helpers
def _guarded(func, args) -> int:
    try:
        with Client(args.url, token=args.token) as api:
            return func(api, args)
    except ApiError as exc:
        field = f" [{exc.field}]" if exc.field else ""
        print(f"error {exc.status_code}{field}: {exc.detail}", file=sys.stderr)
        if exc.status_code == 401:
            print(
                "hint: pass --token or set EVCBENCH_TOKEN; a local service's admin token is <data dir>/admin.token, "
                "found when EVCBENCH_DATA_DIR (default ./var) names that data dir",
                file=sys.stderr,
            )
        return 2
    except httpx.TransportError as exc:
        print(f"error: cannot reach the service at {args.url}: {exc}", file=sys.stderr)
        return 3
    except StopNotDelivered as exc:  # no door answered: no HTTP status to show
        print(f"error: emergency stop not delivered: {exc.detail}", file=sys.stderr)
        return 3


def _finish(args, job: dict, text: str) -> int:
    if job["state"] == "succeeded":
        return _emit(args, job, text)
    _emit(
        args,
        job,
        f"job {job['id']} {job['state']}: {job.get('error') or job.get('message')}"
        + (f"; {text}" if text and job.get("result") else ""),
    )
    return 1


def _emit(args, payload, text: str) -> int:
    print(json.dumps(payload, indent=2) if args.json else text)
    return 0


def _list(text: str) -> list[str]:
    return [part.strip() for part in str(text).split(",") if part.strip()]
