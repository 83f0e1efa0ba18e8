"""SIGTERM / SIGINT: outputs to 0 V and the running bench job cancelled *before* uvicorn shuts down.

``serve`` builds a ``uvicorn.Server`` and calls ``install(server, app)``. Uvicorn installs
``server.handle_exit`` as its signal handler when it starts serving; ``install`` wraps it so that
a signal first drives the bench to 0 V (``Bench.stop``: the running loop stops within one control
period, or 0 V is written from here), then cancels the running bench job with the reason
"stopped by SIGTERM" (its samples so far are kept as a partial dataset), and only then lets uvicorn
shut down normally (lifespan shut-down: the jobs end, the bench closes at 0 V).
"""

from __future__ import annotations

import logging
import signal
from typing import Any

from service.runtime.engine import EngineUnavailable
from service.runtime.stop_port import zero_after_request_ms

log = logging.getLogger("evcbench.safety")


def reason_for(sig: int) -> str:
    """ "stopped by SIGTERM" / "stopped by SIGINT"."""
    try:
        return f"stopped by {signal.Signals(sig).name}"
    except ValueError:
        return f"stopped by signal {sig}"


def safe_state(app: Any, reason: str) -> dict:
    """The outputs go to 0 V first (the running loop stops within one control period, or 0 V is
    written from here), then the bench jobs queued are cancelled and the running bench job is
    cancelled with ``reason``: nothing that touches the store comes before the 0 V. Used by the
    emergency stop and the signal handlers; safe to call more than once and before the app has
    started (then there is nothing to stop). ``stop`` holds the bench's figures (``Bench.last_stop``),
    ``zero_after_request_ms`` the time from the stop reaching the bench to its 0 V write (ms)."""
    state = getattr(app, "state", None)
    bench, jobs = getattr(state, "bench", None), getattr(state, "jobs", None)
    out: dict = {"reason": reason, "cancelled_job_id": None, "cancelled_queued_job_ids": []}
    if bench is not None:
        running = jobs.running_bench_job if jobs is not None else None
        try:
            out["loop_answered"] = bench.stop(reason)
        except EngineUnavailable as exc:
            return _engine_gone(out, bench, jobs, running, exc)
        out["stop"] = stop = dict(bench.last_stop)
        if jobs is not None:
            out["cancelled_job_id"], out["cancelled_queued_job_ids"] = cancel_bench_jobs(jobs, reason, running)
        out["output_v"] = stop["output_v"]
        out["zero_after_request_ms"] = zero_after_request_ms(stop)
    log.warning(
        "%s: outputs at 0 V, %s", reason, cancelled_words(out["cancelled_job_id"], out["cancelled_queued_job_ids"])
    )
    return out


def cancelled_words(running: str | None, queued: list[str]) -> str:
    """The bench jobs a stop cancelled, in words: "running bench job J cancelled, queued K, L cancelled",
    "no bench job was running, none queued" (a fit is no bench job: an emergency stop leaves it be)."""
    ran = f"running bench job {running} cancelled" if running else "no bench job was running"
    return f"{ran}, " + (f"queued {', '.join(queued)} cancelled" if queued else "none queued")


def _engine_gone(out: dict, bench: Any, jobs: Any, running: str | None, exc: EngineUnavailable) -> dict:
    """``safe_state`` without an engine: what could be done, in ``engine_note``. The supervisor
    drives the outputs to 0 V where the hardware lets it and starts a fresh engine, whose first act
    is 0 V; the bench jobs are cancelled here all the same."""
    if jobs is not None:
        out["cancelled_job_id"], out["cancelled_queued_job_ids"] = cancel_bench_jobs(jobs, out["reason"], running)
    done = getattr(bench, "zero_note", None) or "a fresh engine, if the service goes on, writes 0 V as its first act"
    out.update(
        loop_answered=None,
        output_v={},
        zero_after_request_ms=None,
        stop={"zero_monotonic_s": None},
        engine_note=f"{exc}; {done}",
    )
    log.warning("%s without a bench engine: %s", out["reason"], out["engine_note"])
    return out


def cancel_bench_jobs(jobs: Any, reason: str, running: str | None = None) -> tuple[str | None, list[str]]:
    """After a stop: cancel the bench jobs queued (the bench stays still), then the one running, with
    ``reason``. Returns (the running job's id, or ``running`` if it ended meanwhile; the queued ids)."""
    queued = jobs.cancel_queued_bench_jobs(reason)
    return jobs.cancel_running_bench_job(reason) or running, queued


def install(server: Any, app: Any) -> None:
    """Wrap ``server.handle_exit`` (uvicorn's SIGTERM/SIGINT handler) with ``safe_state``."""
    original = server.handle_exit

    def handle_exit(sig: int, frame) -> None:
        supervisor = getattr(getattr(app, "state", None), "supervisor", None)
        if supervisor is not None:
            supervisor.stand_down()  # an engine leaving on this signal is no death to restart from
        try:
            safe_state(app, reason_for(sig))
        except EngineUnavailable as exc:  # a signal to the process group reached the engine first
            log.warning(
                "%s: the bench engine had already gone (%s); an engine that leaves on a signal "
                "writes 0 V on its way out, one killed outright cannot",
                reason_for(sig),
                exc,
            )
        except Exception:  # noqa: BLE001 - never keep uvicorn from shutting down
            log.exception("safe state on signal %s failed", sig)
        original(sig, frame)

    server.handle_exit = handle_exit
