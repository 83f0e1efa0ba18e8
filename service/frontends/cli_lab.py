"""``evcbench lab batch``: batch discovery over a store's datasets (service.lab.batch), in this
process, on a LocalCluster of worker processes, or on a running Dask scheduler. It opens the store
directly (like ``evcbench store check``), so it runs where the store's database and arrays are
reachable; on a scheduler, so must every worker."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from service.runtime.settings import Settings
from service.science.data.units import fmt_nm


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register ``lab`` and its ``batch`` verb on the ``evcbench`` sub-parser."""
    lab = sub.add_parser("lab", help="work across the benches of a lab store (batch discovery)")
    verbs = lab.add_subparsers(dest="lab_command", required=True)
    p = verbs.add_parser("batch", help="identify, diagnose and (with --steps) discover on every dataset and axis")
    p.add_argument(
        "--database-url",
        help="SQLAlchemy URL of the metadata database (default: SQLite in the data dir; env EVCBENCH_DATABASE_URL)",
    )
    p.add_argument("--data-dir", type=Path, help="store directory (default ./var, env EVCBENCH_DATA_DIR)")
    p.add_argument(
        "--array-url",
        help="shared array location (a path or s3://bucket/prefix), when the store has one (env EVCBENCH_ARRAY_URL)",
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--scheduler",
        help="Dask scheduler address, tcp://host:8786 (default: env "
        "EVCBENCH_DASK_SCHEDULER; neither and no --local-workers: run in this process)",
    )
    where.add_argument("--local-workers", type=int, help="start a LocalCluster of this many worker processes")
    p.add_argument("--datasets", help="comma-separated dataset ids (default: every dataset of the store)")
    p.add_argument("--axes", default="y,z", help="comma-separated axes (default y,z)")
    p.add_argument(
        "--steps",
        type=int,
        default=0,
        help="effects the discovery loop may add after the diagnosis (default 0: identify and diagnose only)",
    )
    p.add_argument(
        "--continue-past-ambiguity",
        action="store_true",
        help="at an ambiguity the loop may not test (a batch runs no experiment), add the leading "
        "claimed effect and go on (default: stop there and name the sweep)",
    )
    p.add_argument("--n-operators", type=int, default=10, help="play operators of the hysteresis model (default 10)")
    p.add_argument("--json", action="store_true", help="print the whole result as one JSON object")
    p.set_defaults(func=_cmd_batch)


def _cmd_batch(args: argparse.Namespace) -> int:
    from service.lab.address import StoreAddress
    from service.lab.batch import batch_discover
    from service.lab.cluster import dask_client, scheduler_from_env
    from service.science.errors import FieldError

    defaults = Settings()
    address = StoreAddress.of(
        args.database_url or defaults.database_url,
        args.data_dir or defaults.data_dir,
        args.array_url or defaults.array_url,
    )
    if address.array_url is None and not Path(address.data_dir).is_dir():
        print(f"evcbench lab batch: no store at {address.data_dir}", file=sys.stderr)
        return 2
    local = args.local_workers is not None
    scheduler = args.scheduler or (None if local else scheduler_from_env())
    options = {
        "dataset_ids": _list(args.datasets) if args.datasets else None,
        "axes": tuple(_list(args.axes)),
        "steps": args.steps,
        "n_operators": args.n_operators,
        "continue_past_ambiguity": args.continue_past_ambiguity,
        "on_result": None if args.json else _progress,
    }
    try:
        if scheduler or local:
            with dask_client(scheduler, args.local_workers) as client:
                result = batch_discover(address, client=client, **options)
        else:
            result = batch_discover(address, **options)
    except (FieldError, ValueError) as exc:
        print(f"evcbench lab batch: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(result) if args.json else table(result))
    return 0 if result["failed"] == 0 else 1


def _progress(row: dict, done: int, total: int) -> None:
    print(f"[{done}/{total}] {row['dataset_id']} {row['axis']}: {row['status']}", file=sys.stderr)


def table(result: dict) -> str:
    """One line per dataset and axis: bench, dataset, axis, held-out RMS before and after the loop
    and the noise floor (nm), verdict, claimed effects, effects the loop added and their parameters."""
    lines = [
        f"batch {result['batch_id']}: {result['ok']} ok, {result['skipped']} skipped, {result['failed']} failed "
        f"(steps {result['steps']})",
        f"{'bench':<14} {'dataset':<20} {'axis':<4} {'held-out nm':>11} {'after nm':>9} {'noise nm':>9} "
        f"{'verdict':<15} claimed | found (parameters)",
    ]
    for r in result["results"]:
        head = f"{str(r.get('bench_id') or '-'):<14} {r['dataset_id']:<20} {r['axis']:<4}"
        if r.get("status") != "ok":
            lines.append(f"{head} {r.get('status')}: {r.get('reason') or r.get('error')}")
            continue
        found = "; ".join(
            " ".join([e] + [f"{k} {v:.4g}" for k, v in r["physical_parameters"].get(e, {}).items()])
            for e in r["effects_found"]
        )
        lines.append(
            f"{head} {_nm(r['held_out_rms_um']):>11} {_nm(r['held_out_rms_after_um']):>9} "
            f"{_nm(r['noise_floor_um']):>9} {r['verdict']:<15} {','.join(r['claimed_effects']) or '-'}"
            + (f" | {found}" if found else "")
        )
    return "\n".join(lines)


def _nm(value_um) -> str:
    """An error (µm) for the table's nm columns: the number alone."""
    return "-" if value_um is None else fmt_nm(value_um).removesuffix(" nm")


def _list(text: str) -> list[str]:
    return [part.strip() for part in str(text).split(",") if part.strip()]
