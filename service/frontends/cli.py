"""The ``evcbench`` command line: serve the API, run benchmarks, and drive a running service
(sweep, import, identify, compare, jobs, datasets, models: see service/frontends/cli_remote.py)."""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import threading
from collections.abc import Callable
from importlib.metadata import entry_points
from pathlib import Path

from service.runtime.settings import Settings


def _cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from service.http.app import create_app

    try:
        settings = _serve_settings(args)
    except ValueError as exc:  # a bad --stop-port, EVCBENCH_* value or bench id: one line
        print(f"evcbench serve: {exc}", file=sys.stderr)
        return 2
    from service.frontends.cli_tokens import serve_refusal
    from service.runtime.safe_shutdown import install

    refusal = serve_refusal(settings)
    if refusal:
        print(f"evcbench serve: {refusal}", file=sys.stderr)
        return 2
    app = create_app(settings)
    server = uvicorn.Server(
        uvicorn.Config(
            app,
            host=settings.host,
            port=settings.port,
            log_level="info",
            timeout_graceful_shutdown=GRACEFUL_SHUTDOWN_S,
        )
    )
    install(server, app)  # SIGTERM/SIGINT: 0 V and the running job cancelled, then the normal shut-down
    try:
        server.run()
    finally:  # also when uvicorn re-raises Ctrl-C's KeyboardInterrupt after its shut-down
        exit_if_work_is_left(getattr(app.state, "jobs", None))
    return 0


#: how long Ctrl-C or SIGTERM waits for requests still being answered before it cancels them (s); the
#: outputs are at 0 V before this wait (service.runtime.safe_shutdown). A walk's Ctrl-C waited at
#: "Waiting for background tasks to complete" for over 45 s with no job running, and a second Ctrl-C
#: did not end the process.
GRACEFUL_SHUTDOWN_S = 5.0


def exit_if_work_is_left(jobs) -> None:
    """After the service's shut-down (the bench closed at 0 V, the store closed, every job ended in
    it): exit now if a job's thread, or a request's worker thread, is still at work — work outside a
    discover or identify fit sees its cancel only between its steps, and the interpreter would
    otherwise wait for it at exit, minutes with Ctrl-C seemingly ignored."""
    job_left = jobs is not None and jobs.job_threads_alive()
    others = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon and t.is_alive()]
    if job_left or others:
        what = "a job" if job_left else f"{len(others)} thread(s) still answering"
        logging.getLogger("evcbench.jobs").warning("exiting without waiting for %s that did not stop", what)
        logging.shutdown()
        os._exit(0)


def _serve_settings(args: argparse.Namespace) -> Settings:
    """The service's settings: the command line over the environment (EVCBENCH_*) over the defaults."""
    try:
        defaults = Settings()
    except ValueError as exc:
        raise ValueError(f"the environment's EVCBENCH_* settings: {exc}") from None
    return Settings(
        data_dir=args.data_dir or defaults.data_dir,
        bench=args.bench or defaults.bench,
        seed=args.seed if args.seed is not None else defaults.seed,
        host=args.host or defaults.host,
        port=args.port or defaults.port,
        stop_port=args.stop_port if args.stop_port is not None else defaults.stop_port,
        database_url=args.database_url or defaults.database_url,
        auth=args.auth or defaults.auth,
        array_url=args.array_url or defaults.array_url,
        effects_dir=str(args.effects_dir) if args.effects_dir else defaults.effects_dir,
        # a lab: unless given, the id derives from the bench and the URL from host and port (Settings)
        **({"bench_id": args.bench_id} if args.bench_id else {}),
        **({"public_url": args.public_url} if args.public_url else {}),
    )


def _cmd_warm(args: argparse.Namespace) -> int:
    from service.runtime.warmup import warm

    try:
        took = warm(args.parts or None)
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 2
    print(
        json.dumps(took)
        if args.json
        else "compiled into numba's cache: " + ", ".join(f"{part} {s:.1f} s" for part, s in took.items())
    )
    return 0


def get_benchmark(name: str) -> Callable[[], dict]:
    """The benchmark registered as ``name`` (service.perf, pyproject.toml's "evcbench.benchmarks"
    entry points); KeyError lists the known names."""
    found = {ep.name: ep for ep in entry_points(group="evcbench.benchmarks")}
    if name not in found:
        raise KeyError(f"unknown benchmark {name!r}; known: {', '.join(sorted(found))}")
    return found[name].load()


def _cmd_bench(args: argparse.Namespace) -> int:
    import inspect

    try:
        benchmark = get_benchmark(args.name)
    except KeyError as exc:
        print(exc.args[0], file=sys.stderr)
        return 2
    if args.duration is None:
        result = benchmark()
    elif "duration_s" in inspect.signature(benchmark).parameters:
        result = benchmark(duration_s=args.duration)
    else:
        print(f"--duration: the {args.name} benchmark has no duration (only: service)", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:>32}: {value}")
    return 0


def _cmd_store_check(args: argparse.Namespace) -> int:
    from service.frontends.cli_tokens import open_store
    from service.store.check import check_store, format_report

    data_dir = Path(args.data_dir or Settings().data_dir)
    if not data_dir.is_dir():
        print(f"no store at {data_dir}", file=sys.stderr)
        return 2
    store = open_store(args.data_dir, args.database_url, args.array_url)
    try:
        report = check_store(store, quick=args.quick, offline=args.offline)
    finally:
        store.close()
    print(json.dumps(report) if args.json else format_report(report))
    return 0 if report["ok"] else 1


def _cmd_store_repair(args: argparse.Namespace) -> int:
    from service.frontends.cli_tokens import open_store
    from service.runtime.repair import StoreBusy, format_repair, repair_store

    data_dir = Path(args.data_dir or Settings().data_dir)
    if not data_dir.is_dir():
        print(f"no store at {data_dir}", file=sys.stderr)
        return 2
    logging.getLogger("evcbench.recovery").setLevel(logging.ERROR)  # the report below says it all
    store = open_store(args.data_dir, args.database_url, args.array_url)
    try:
        report = repair_store(store, dry_run=args.dry_run)
    except StoreBusy as exc:
        print(f"evcbench store repair: {exc}", file=sys.stderr)
        return 2
    finally:
        store.close()
    print(json.dumps(report) if args.json else format_repair(report))
    return 0 if args.dry_run or report["after"]["ok"] else 1


ARRAY_URL_HELP = (
    "the lab's shared array location: a path or file:// URL (an NFS mount) or s3://bucket/prefix "
    "(endpoint EVCBENCH_S3_ENDPOINT_URL, AWS_* credentials); default <data-dir>/arrays; "
    "env EVCBENCH_ARRAY_URL"
)


def build_parser() -> argparse.ArgumentParser:
    """The ``evcbench`` command line: serve, bench, warm and store here; the REST verbs, tokens and the
    lab from cli_remote, cli_tokens and cli_lab."""
    parser = argparse.ArgumentParser(prog="evcbench", description="EVC Bench: piezo bench service and tools.")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_serve(sub)
    _add_tools(sub)
    _add_store(sub)
    from service.frontends import cli_effects, cli_lab, cli_remote, cli_tokens

    cli_remote.add_commands(sub)  # sweep, import, identify, compare, jobs, datasets, models (over REST)
    cli_tokens.add_commands(sub)  # token create | list | revoke (on the store)
    cli_lab.add_commands(sub)  # lab batch (on the store, in process or on Dask)
    cli_effects.add_commands(sub)  # effects check | list (plug-in effects)
    return parser


def _add_serve(sub) -> None:
    """``evcbench serve``: its options, each over the environment's EVCBENCH_* setting."""
    serve = sub.add_parser("serve", help="start the REST service")
    serve.add_argument(
        "--host",
        help="bind address (default 127.0.0.1; any other address needs auth on and "
        "a token from `evcbench token create`)",
    )
    serve.add_argument("--port", type=int, help="TCP port (default 8000)")
    serve.add_argument(
        "--stop-port",
        type=int,
        help="the emergency stop's own port, served by the bench engine "
        "(default: any free one, named in GET /api/bench and the log; env EVCBENCH_STOP_PORT)",
    )
    serve.add_argument("--data-dir", type=Path, help="store directory (default ./var)")
    serve.add_argument("--bench", help="bench config name in fixtures/benches/ or a path (default: default)")
    serve.add_argument("--seed", type=int, help="seed of the emulated bench's noise")
    serve.add_argument(
        "--database-url",
        help="SQLAlchemy URL of the metadata database (default: SQLite in the data dir; env EVCBENCH_DATABASE_URL)",
    )
    serve.add_argument(
        "--auth", choices=("tokens", "off"), help="tokens (default; env EVCBENCH_AUTH) or off (loopback only)"
    )
    serve.add_argument("--array-url", help=ARRAY_URL_HELP)
    serve.add_argument(
        "--effects-dir",
        type=Path,
        help="a directory of plug-in effects (*.py; docs/how-to/add-your-own-effect.md); "
        "default: $EVCBENCH_EFFECTS_DIR",
    )
    serve.add_argument(
        "--bench-id",
        help="this bench's id in a lab of services on one database (default: from "
        "--bench, e.g. 'creep'; env EVCBENCH_BENCH_ID)",
    )
    serve.add_argument(
        "--public-url", help="where the lab reaches this service (default http://HOST:PORT; env EVCBENCH_PUBLIC_URL)"
    )
    serve.set_defaults(func=_cmd_serve)


def _add_tools(sub) -> None:
    """``evcbench bench`` (a benchmark) and ``evcbench warm`` (numba's cache)."""
    bench = sub.add_parser("bench", help="run a benchmark and print its figures")
    bench.add_argument("name", help="emulator | identification | …")
    bench.add_argument("--json", action="store_true", help="print one JSON object")
    bench.add_argument("--duration", type=float, help="service: seconds of load (default 60)")
    bench.set_defaults(func=_cmd_bench)

    warm = sub.add_parser(
        "warm",
        help="compile the kernels into numba's cache now, so that the first sweep, fit "
        "or tracking run of a fresh install does not wait for the compiler",
    )
    warm.add_argument("parts", nargs="*", help="emulator, models, loop (default: all)")
    warm.add_argument("--json", action="store_true", help="print one JSON object: seconds per part")
    warm.set_defaults(func=_cmd_warm)


def _add_store(sub) -> None:
    """``evcbench store check | repair``."""
    store = sub.add_parser("store", help="maintain the store (check, repair)")
    store_sub = store.add_subparsers(dest="store_command", required=True)

    def store_verb(name: str, help_text: str, func) -> argparse.ArgumentParser:
        verb = store_sub.add_parser(name, help=help_text)
        verb.add_argument("--data-dir", type=Path, help="store directory (default ./var)")
        verb.add_argument(
            "--database-url", help="SQLAlchemy URL of the metadata database (default: SQLite in the data dir)"
        )
        verb.add_argument("--array-url", help=ARRAY_URL_HELP)
        verb.add_argument("--json", action="store_true", help="print one JSON object")
        verb.set_defaults(func=func)
        return verb

    check = store_verb("check", "report inconsistencies between rows and files; exit 1 if any", _cmd_store_check)
    check.add_argument("--quick", action="store_true", help="skip the SHA-256 of every array file")
    check.add_argument(
        "--offline", action="store_true", help="no service runs on this store: a queued or running job is a problem too"
    )
    repair = store_verb(
        "repair",
        "fix what `store check` finds, never deleting a dataset row (the service must "
        "be stopped); exit 1 if problems remain",
        _cmd_store_repair,
    )
    repair.add_argument("--dry-run", action="store_true", help="change nothing; say what would be done")


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
