"""``evcbench serve`` as a real process on a free loopback port, for end-to-end and browser tests."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class Server:
    """``evcbench serve`` in a subprocess with its own data dir and port. ``token`` is the service's
    bootstrap admin token (<data_dir>/admin.token), ``headers`` carry it, ``dashboard_url()``
    opens the dashboard with it already stored in the browser."""

    def __init__(self, data_dir: Path, log: Path, bench: str = "default", seed: int = 1):
        self.port = _free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = log
        self.data_dir = Path(data_dir)
        self.token: str | None = None
        env = {k: v for k, v in os.environ.items() if not k.startswith("EVCBENCH_")}
        env["OPENBLAS_NUM_THREADS"] = "1"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "service.cli", "serve", "--host", "127.0.0.1", "--port", str(self.port),
             "--data-dir", str(data_dir), "--bench", bench, "--seed", str(seed)],
            cwd=ROOT, env=env, stdout=log.open("ab"), stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise AssertionError(f"the service exited with {self.proc.returncode}:\n{log.read_text()}")
            try:
                if httpx.get(f"{self.url}/api/health", timeout=1).status_code == 200:
                    self.token = (self.data_dir / "admin.token").read_text().strip()
                    return
            except httpx.TransportError:
                pass
            time.sleep(0.2)
        self.proc.kill()
        raise AssertionError(f"the service did not answer within 120 s:\n{log.read_text()}")

    @property
    def headers(self) -> dict:
        """The header that authenticates a request to this server (admin scope)."""
        return {"Authorization": f"Bearer {self.token}"}

    def dashboard_url(self, route: str = "bench") -> str:
        """The dashboard at ``#/route`` with ``token=`` in the fragment: the page stores it in
        localStorage and removes it from the address (a fragment never reaches the server)."""
        return f"{self.url}/web/#/{route}{'&' if '?' in route else '?'}token={self.token}"

    def stop(self) -> bool:
        """SIGTERM, then True if the process ran its shut-down and exited cleanly. (Uvicorn
        re-raises the signal after a graceful shut-down, so the exit status may be −SIGTERM.)"""
        self.proc.send_signal(signal.SIGTERM)
        try:
            code = self.proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise AssertionError(f"the service ignored SIGTERM:\n{self.log.read_text()}")
        text = self.log.read_text()
        return code in (0, -signal.SIGTERM) and text.rstrip().endswith(
            f"Finished server process [{self.proc.pid}]") and "Application shutdown complete." in text
