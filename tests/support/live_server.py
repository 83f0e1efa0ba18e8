"""``evcbench serve`` as a real process on a free loopback port, for end-to-end and browser tests
(its own data dir and log under the test's tmp_path, so xdist workers never share one)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import httpx

from service.perf.service_load import ROOT, spawn_service  # noqa: F401  (ROOT re-exported for tests)
from service.security.auth import read_bootstrap_token


class Server:
    """``evcbench serve`` in a subprocess with its own data dir and port. ``token`` is the service's
    bootstrap admin token (<data_dir>/admin.token), ``headers`` carry it, ``dashboard_url()``
    opens the dashboard with it already stored in the browser."""

    def __init__(
        self,
        data_dir: Path,
        log: Path,
        bench: str = "default",
        seed: int = 1,
        env: dict[str, str] | None = None,
        own_group: bool = False,
    ):
        """``env``: EVCBENCH_* settings of the service (e.g. a lab's database URL and bench id);
        ``own_group``: the service and its engine in a process group of their own (``stop(group=True)``)."""
        self.log = log
        self.data_dir = Path(data_dir)
        for attempt in range(3):
            try:
                self.proc, self.url = spawn_service(
                    self.data_dir, bench, log, seed=seed, extra_env=env, own_group=own_group
                )
                break
            except RuntimeError as exc:
                # The free port is found by binding port 0 and closing it: under pytest-xdist another
                # worker's service may take it before this one binds. Another free port then.
                if attempt == 2 or "address already in use" not in str(exc).lower():
                    raise
        self.port = httpx.URL(self.url).port
        self.token = read_bootstrap_token(self.data_dir)

    @property
    def headers(self) -> dict:
        """The header that authenticates a request to this server (admin scope)."""
        return {"Authorization": f"Bearer {self.token}"}

    def dashboard_url(self, route: str = "bench") -> str:
        """The dashboard at ``#/route`` with ``token=`` in the fragment: the page stores it in
        localStorage and removes it from the address (a fragment never reaches the server)."""
        return f"{self.url}/web/#/{route}{'&' if '?' in route else '?'}token={self.token}"

    def stop(self, group: bool = False) -> bool:
        """SIGTERM (``group``: to the whole process group, engine included, as a shell's kill of
        `make run` does), then True if the process ran its shut-down and exited cleanly. (Uvicorn
        re-raises the signal after a graceful shut-down, so the exit status may be −SIGTERM.)"""
        if group:
            os.killpg(self.proc.pid, signal.SIGTERM)
        else:
            self.proc.send_signal(signal.SIGTERM)
        try:
            code = self.proc.wait(timeout=60)
        except subprocess.TimeoutExpired as exc:
            self.proc.kill()
            raise AssertionError(f"the service ignored SIGTERM:\n{self.log.read_text()}") from exc
        text = self.log.read_text()
        return (
            code in (0, -signal.SIGTERM)
            and text.rstrip().endswith(f"Finished server process [{self.proc.pid}]")
            and "Application shutdown complete." in text
        )


def evcbench(server: Server, *args: str, timeout_s: float = 120) -> subprocess.CompletedProcess:
    """``evcbench <args> --url <service>`` as a lab user runs it beside the service: the token comes
    from <data dir>/admin.token (EVCBENCH_TOKEN is not passed on)."""
    env = {**{k: v for k, v in os.environ.items() if k != "EVCBENCH_TOKEN"}, "EVCBENCH_DATA_DIR": str(server.data_dir)}
    return subprocess.run(
        [sys.executable, "-m", "service.frontends.cli", *args, "--url", server.url],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )
