"""The web process's side of the engine's stop port (service.runtime.stop_port).

``StopPortLink`` keeps the port's token list equal to the store's valid tokens (their SHA-256
digests and scopes: the engine never reads the store), and cancels the bench's jobs after the port
stopped the bench. The list is sent at start-up, at once when this process creates or revokes a
token, and otherwise every ``REFRESH_S``, which is how long a token revoked elsewhere (the CLI,
another service of the lab) may still press the stop there: the stop only drives the outputs to
0 V and cancels the bench's jobs, so that is the direction to err in.
"""

from __future__ import annotations

import json
import logging
import threading
from pathlib import Path
from typing import Any

from service.runtime.engine import EngineUnavailable
from service.runtime.safe_shutdown import cancel_bench_jobs, cancelled_words
from service.runtime.stop_port import STOP_PORT_FILE
from service.store.files import write_bytes_atomic

log = logging.getLogger("evcbench.safety")

#: How often the token list is re-read from the store (s).
REFRESH_S = 2.0


class StopPortLink:
    """Connect an ``EngineBench``'s stop port to the app: tokens and job cancellation."""

    def __init__(
        self,
        bench: Any,
        store: Any,
        jobs: Any,
        auth_off: bool,
        refresh_s: float = REFRESH_S,
        announce: tuple[Path, int, str] | None = None,
    ):
        """``announce``: (data dir, the service's port, bench id) to write ``STOP_PORT_FILE`` there."""
        self.bench, self.store, self.jobs, self.auth_off = bench, store, jobs, auth_off
        self.announce = announce
        self.refresh_s = refresh_s
        self._sent: dict | None = None
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> StopPortLink:
        """Send the tokens now (before the service answers anyone), then keep them current."""
        self.bench.run_owner = lambda: self.jobs.running_bench_job
        self.bench.on_port_stop = self._cancel_jobs
        self.bench.on_attach = self.reattach
        self.refresh()
        self._thread = threading.Thread(target=self._keep_current, name="evc-stop-tokens", daemon=True)
        self._thread.start()
        self._announce()
        return self

    def _announce(self) -> None:
        """Write ``STOP_PORT_FILE`` (the engine's stop port, for a local ``evcbench stop``)."""
        if self.announce is not None:
            data_dir, service_port, bench_id = self.announce
            write_bytes_atomic(
                Path(data_dir) / STOP_PORT_FILE,
                json.dumps(
                    {"service_port": service_port, "stop_port": self.bench.stop_port, "bench_id": bench_id}
                ).encode(),
            )

    def reattach(self) -> None:
        """A fresh engine was attached (service.runtime.supervisor): its stop port learns the
        tokens, and the file names its port."""
        with self._lock:
            self._sent = None
        try:
            self.refresh()
        except EngineUnavailable as exc:
            log.warning("the fresh engine's stop port has no tokens yet: %s", exc)
        self._announce()

    def close(self) -> None:
        self._closing.set()
        if self._thread is not None:
            self._thread.join(5.0)
        if self.announce is not None:
            (Path(self.announce[0]) / STOP_PORT_FILE).unlink(missing_ok=True)

    def refresh(self) -> None:
        """Read the valid tokens from the store and send them to the engine if they changed."""
        with self._lock:
            current = {} if self.auth_off else self.store.tokens.valid_digests()
            if current != self._sent:
                self.bench.set_stop_tokens(current, self.auth_off)
                self._sent = current

    def _keep_current(self) -> None:
        while not self._closing.wait(self.refresh_s):
            try:
                self.refresh()
            except EngineUnavailable:
                pass  # no engine now: the fresh one gets the list as it is attached (reattach)
            except Exception:  # noqa: BLE001 - a store hiccup: the port keeps the last list; try again
                log.exception("could not send the stop port its tokens")

    def _cancel_jobs(self, reason: str) -> None:
        running, queued = cancel_bench_jobs(self.jobs, reason)
        log.warning("%s (stop port): outputs at 0 V, %s", reason, cancelled_words(running, queued))


def refresh_stop_tokens(app: Any) -> None:
    """After this process created or revoked a token: the stop port learns it at once."""
    link = getattr(app.state, "stop_port_link", None)
    if link is not None:
        try:
            link.refresh()
        except EngineUnavailable:
            pass  # no engine now: the fresh one gets the list as it is attached
