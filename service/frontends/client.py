"""A small Python client of the EVC Bench REST API (used by the CLI and the tests).

    from service.frontends.client import Client
    api = Client("http://127.0.0.1:8000")
    job = api.sweep(axes=["y"], frequencies_hz=[1, 10], cycles=5, wait=True)
    model = api.identify("y", [job["result"]["dataset_id"]], model="static_pi")
    print(api.compare(model["id"], job["result"]["dataset_id"])["metrics"])

Every non-2xx answer raises ApiError with the server's ``detail`` and the ``field`` at fault.
The API token is ``token=``, else $EVCBENCH_TOKEN, else (for a loopback URL) the local service's
bootstrap token in <data_dir>/admin.token (data_dir: ``data_dir=``, $EVCBENCH_DATA_DIR or ./var).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import httpx
import numpy as np

from service.runtime.stop_port import STOP_PORT_FILE
from service.security.binding import is_loopback

DEFAULT_URL = "http://127.0.0.1:8000"
TERMINAL_STATES = ("succeeded", "failed", "cancelled")
ProgressCallback = Callable[[dict], None]
_NOT_LOOKED_UP = object()
#: How long a stop pressed on the service's own route may take before the client gives up (s).
STOP_ROUTE_TIMEOUT_S = 10.0
#: The stop port answers within milliseconds (it waits at most the bench's stop_wait_s for the loop):
#: past this the client presses the service's own route instead.
STOP_PORT_TIMEOUT = httpx.Timeout(2.0, connect=1.0)


class ApiError(RuntimeError):
    """The service refused a request: ``status_code``, ``detail`` (words) and ``field``."""

    def __init__(self, status_code: int, detail: str, field: str | None = None):
        super().__init__(f"{status_code}: {detail}")
        self.status_code, self.detail, self.field = status_code, detail, field


class StopNotDelivered(RuntimeError):
    """An emergency stop no door took: neither the stop port nor the service's own route answered
    (no HTTP status was received). ``detail`` says what happened at each door, in words."""

    def __init__(self, detail: str):
        super().__init__(detail)
        self.detail = detail


def _transport_words(exc: httpx.TransportError, timeout_s: float) -> str:
    """What a failed connection was, in words: refused, no answer within ``timeout_s`` (s), or its kind."""
    if isinstance(exc, httpx.ConnectError):
        reason = str(exc).split("] ", 1)[-1].lower() or "no connection"  # "[Errno 111] Connection refused"
        return f"could not connect ({reason})"
    if isinstance(exc, httpx.TimeoutException):
        return f"no answer within {timeout_s:g} s"
    return f"the connection failed ({type(exc).__name__}: {exc})"


def resolve_token(base_url: str, token: str | None = None, data_dir: str | Path | None = None) -> str | None:
    """The token to send: ``token``, $EVCBENCH_TOKEN, or <data_dir>/admin.token for a loopback URL."""
    token = token or os.environ.get("EVCBENCH_TOKEN")
    if token or not is_loopback(httpx.URL(base_url).host):
        return token or None
    from service.security.auth import read_bootstrap_token

    return read_bootstrap_token(data_dir or os.environ.get("EVCBENCH_DATA_DIR") or "var")


class Client:
    """Talks to one service. ``http`` may be any httpx.Client (e.g. FastAPI's TestClient), whose
    own headers then carry the token unless ``token`` is given."""

    def __init__(
        self,
        base_url: str = DEFAULT_URL,
        timeout_s: float = 60.0,
        http: httpx.Client | None = None,
        token: str | None = None,
        data_dir: str | Path | None = None,
    ):
        self._data_dir = Path(data_dir or os.environ.get("EVCBENCH_DATA_DIR") or "var")
        if http is None:
            http = httpx.Client(base_url=base_url.rstrip("/"), timeout=timeout_s)
            token = resolve_token(base_url, token, data_dir)
        if token:
            http.headers["Authorization"] = f"Bearer {token}"
        self.http = http
        self._stop_url: str | None | object = _NOT_LOOKED_UP
        self._stop_http: httpx.Client | None = None  # the stop port's own client, made by prepare_stop

    def close(self) -> None:
        self.http.close()
        if self._stop_http is not None:
            self._stop_http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ bench
    def health(self) -> dict:
        return self._request("GET", "/api/health")

    def bench(self) -> dict:
        return self._request("GET", "/api/bench")

    def stop_bench(self) -> dict:
        """Emergency stop: 0 V now, and the running bench job is cancelled. Pressed on the bench
        engine's stop port, which waits for nothing the service's web process does, if the service
        has one (``prepare_stop`` looks it up; the first stop does if it was not called); if that
        port cannot be reached or does not stop this bench (any answer but 200: unreachable, a token
        it has not learnt yet, another bench's port), on ``POST /api/bench/stop`` of the service
        itself, waiting at most ``STOP_ROUTE_TIMEOUT_S``. The answer then says why the port was not
        used (``stop_port_refusal``); a service that does not answer either raises StopNotDelivered
        saying what happened at both (the service's own refusal, an HTTP answer, is ApiError)."""
        url, refusal = self.prepare_stop(), None
        if url is not None:
            try:
                response = self._stop_http.post(
                    url, headers={"Authorization": self.http.headers.get("Authorization", "")}
                )
                if response.status_code == 200:
                    return response.json()
                refusal = f"{response.status_code}: {_detail(response)}"
            except httpx.TransportError as exc:  # unreachable from here (a firewall): the service's own route
                refusal = f"{url} unreachable: {_transport_words(exc, STOP_PORT_TIMEOUT.read)}"
        try:
            answer = self._request("POST", "/api/bench/stop", timeout=STOP_ROUTE_TIMEOUT_S)
        except httpx.TransportError as exc:
            raise StopNotDelivered(
                f"could not reach the service at {str(self.http.base_url).rstrip('/')}: {_transport_words(exc, STOP_ROUTE_TIMEOUT_S)}; "
                + (f"its stop port: {refusal}" if refusal else "no stop port known")
                + ": the outputs were NOT commanded to 0 V by this call"
            ) from None
        return answer if refusal is None else {**answer, "stop_port_refusal": refusal}

    def prepare_stop(self) -> str | None:
        """The URL of the engine's stop port (the host this client reaches the service by, the port
        ``GET /api/bench`` names, with ``?bench_id=`` so that another bench's port refuses it),
        looked up once; None if the service has no stop port."""
        if self._stop_url is _NOT_LOOKED_UP:
            host = self.http.base_url.host  # "testserver": an in-process test client has no network
            found = None if host in ("", "testserver") else self._stop_port_lookup()
            self._stop_url = (
                None
                if found is None
                else str(
                    self.http.base_url.copy_with(
                        port=found["stop_port"], path="/api/bench/stop", params={"bench_id": found["bench_id"]}
                    )
                )
            )
            if self._stop_url is not None:  # made here, not at the press: a client costs tens of ms to make
                self._stop_http = httpx.Client(timeout=STOP_PORT_TIMEOUT)
        return self._stop_url

    def _stop_port_lookup(self) -> dict | None:
        """``{"stop_port", "bench_id"}``: from the file a service on this machine writes
        (<data_dir>/stop_port.json, service.runtime.stop_port_link), so that a local ``evcbench stop``
        needs nothing of the web process; else from ``GET /api/bench`` (2 s at most); else None."""
        url = self.http.base_url
        if is_loopback(url.host):
            try:
                local = json.loads((self._data_dir / STOP_PORT_FILE).read_text())
                if local.get("service_port") == url.port:
                    return local
            except (OSError, ValueError):
                pass
        try:
            bench = self.http.get("/api/bench", timeout=STOP_PORT_TIMEOUT)
            if bench.status_code == 200 and (bench.json().get("engine") or {}).get("stop_port") is not None:
                return {"stop_port": bench.json()["engine"]["stop_port"], "bench_id": bench.json()["bench_id"]}
        except (httpx.TransportError, ValueError):
            pass
        return None

    def reset_bench(self) -> dict:
        """Clear latched amplifier faults and the watchdog's trip (409 while a job runs):
        {"cleared": [...], "remaining": reason | None, "output_v": {...}}."""
        return self._request("POST", "/api/bench/reset")

    # ------------------------------------------------------------------ jobs
    def job(self, job_id: str) -> dict:
        return self._request("GET", f"/api/jobs/{job_id}")

    def jobs(self, limit: int = 100, kind: str | None = None, model_id: str | None = None) -> list[dict]:
        """The newest jobs; ``kind`` and ``model_id`` narrow them as GET /api/jobs does."""
        filters = {k: v for k, v in (("kind", kind), ("model_id", model_id)) if v is not None}
        return self._request("GET", "/api/jobs", params={"limit": limit, **filters})

    def cancel(self, job_id: str) -> dict:
        return self._request("DELETE", f"/api/jobs/{job_id}")

    def events(self, job_id: str) -> Iterator[tuple[str, dict]]:
        """The job's server-sent events as (event, job) pairs, ending with ("end", final job)."""
        with self.http.stream("GET", f"/api/jobs/{job_id}/events", timeout=None) as response:
            if response.status_code >= 400:
                response.read()
                self._raise(response)
            event, data = "message", []
            for line in response.iter_lines():
                if line.startswith("event:"):
                    event = line[6:].strip()
                elif line.startswith("data:"):
                    data.append(line[5:].strip())
                elif not line and data:
                    yield event, json.loads("\n".join(data))
                    event, data = "message", []

    def wait(self, job_id: str, on_progress: ProgressCallback | None = None, timeout_s: float | None = None) -> dict:
        """Follow a job until it ends (SSE; polling if the stream breaks); returns the final job."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        try:
            for event, job in self.events(job_id):
                if event == "error":  # the stream ended because the token is no longer valid
                    raise ApiError(job.get("status", 401), job.get("detail", "event stream refused"), job.get("field"))
                if on_progress:
                    on_progress(job)
                if job["state"] in TERMINAL_STATES:
                    return job
                if deadline and time.monotonic() > deadline:
                    break
        except httpx.TransportError:
            pass
        while True:
            job = self.job(job_id)
            if on_progress:
                on_progress(job)
            if job["state"] in TERMINAL_STATES:
                return job
            if deadline and time.monotonic() > deadline:
                raise TimeoutError(f"job {job_id} is still {job['state']} after {timeout_s} s")
            time.sleep(0.2)

    # ------------------------------------------------------------------ sweeps and datasets
    def start_sweep(self, **plan) -> dict:
        """Queue a sweep (fields as in POST /api/sweeps); returns ``{"job_id", …}``."""
        return self._request("POST", "/api/sweeps", json=plan)

    def sweep(self, wait: bool = True, on_progress: ProgressCallback | None = None, **plan) -> dict:
        """Run a sweep; with ``wait`` return the finished job (its result has ``dataset_id``)."""
        started = self.start_sweep(**plan)
        return self.wait(started["job_id"], on_progress) if wait else self.job(started["job_id"])

    def import_dataset(
        self,
        file: str | Path | bytes,
        *,
        filename: str | None = None,
        name: str | None = None,
        axis: str | None = None,
        columns: dict | str | None = None,
        sample_rate_hz: float | None = None,
        delimiter: str | None = None,
    ) -> dict:
        """Upload a CSV/table (a path, streamed from disk, or bytes) as a dataset; returns its record."""
        form = {
            "name": name,
            "axis": axis,
            "sample_rate_hz": sample_rate_hz,
            "delimiter": delimiter,
            "columns": json.dumps(columns) if isinstance(columns, dict) else columns,
        }
        form = {k: str(v) for k, v in form.items() if v is not None}
        if isinstance(file, (str, Path)):
            with open(file, "rb") as handle:
                return self._request(
                    "POST",
                    "/api/datasets",
                    data=form,
                    files={"file": (filename or Path(file).name, handle, "text/csv")},
                )
        return self._request(
            "POST", "/api/datasets", data=form, files={"file": (filename or "upload.csv", file, "text/csv")}
        )

    def datasets(self) -> list[dict]:
        return self._request("GET", "/api/datasets")

    def dataset(self, dataset_id: str) -> dict:
        return self._request("GET", f"/api/datasets/{dataset_id}")

    def dataset_data(self, dataset_id: str, format: str = "json", max_points: int | None = None):
        """JSON arrays (dict) decimated by the service to at most ``max_points`` points per column
        (default: the service's, 10 000; ``stride`` says by how much), or the whole CSV text / HDF5
        bytes with ``format="csv"``/``"hdf5"``. For every sample as numpy arrays use ``dataset_arrays``."""
        params = {"format": format, **({"max_points": max_points} if max_points else {})}
        response = self._send("GET", f"/api/datasets/{dataset_id}/data", params=params)
        return response.json() if format == "json" else response.text if format == "csv" else response.content

    def dataset_chunks(self, dataset_id: str) -> Iterator[dict[str, np.ndarray]]:
        """Every sample of a dataset, streamed (NDJSON) a chunk of rows at a time: dicts of numpy
        arrays ``{"t_s": ..., "u_y_v": ..., …}`` of a few thousand rows each, in order."""
        lines = self._ndjson(dataset_id)
        header = next(lines)
        for chunk in lines:
            yield {name: np.asarray(chunk[name]) for name in header["columns"]}

    def dataset_arrays(self, dataset_id: str) -> dict[str, np.ndarray]:
        """Every sample of a dataset as numpy arrays, streamed (NDJSON) and filled in chunk by chunk:
        only the arrays themselves grow with the dataset."""
        lines = self._ndjson(dataset_id)
        header = next(lines)
        out: dict[str, np.ndarray] = {}
        for chunk in lines:
            start = chunk["start"]
            for name in header["columns"]:
                values = np.asarray(chunk[name])
                if name not in out:
                    out[name] = np.empty(header["samples"], dtype=values.dtype)
                out[name][start : start + values.size] = values
        return out

    def label_dataset(self, dataset_id: str, **labels) -> dict:
        """Set some of a dataset's ``name``, ``tags`` (a list) and ``notes``; returns its record."""
        return self._request("PATCH", f"/api/datasets/{dataset_id}", json=labels)

    def delete_dataset(self, dataset_id: str, cascade: bool = False) -> dict:
        """Delete a dataset and its arrays (ApiError 409 naming the models fitted on it unless
        ``cascade``); returns ``{"datasets", "models", "freed_bytes"}`` deleted."""
        return self._request("DELETE", f"/api/datasets/{dataset_id}", params={"cascade": cascade})

    def _ndjson(self, dataset_id: str) -> Iterator[dict]:
        """The objects of ``GET /api/datasets/{id}/data?format=ndjson``: the header, then the chunks."""
        with self.http.stream(
            "GET", f"/api/datasets/{dataset_id}/data", params={"format": "ndjson"}, timeout=None
        ) as response:
            if response.status_code >= 400:
                response.read()
                self._raise(response)
            for line in response.iter_lines():
                if line:
                    yield json.loads(line)

    # ------------------------------------------------------------------ models
    def start_identify(
        self,
        axis: str,
        datasets: Sequence[str],
        model: str = "static_pi",
        effects: Sequence[str] = ("hysteresis",),
        n_operators: int = 10,
        name: str | None = None,
    ) -> dict:
        body = {
            "axis": axis,
            "datasets": list(datasets),
            "model": model,
            "effects": list(effects),
            "n_operators": n_operators,
            **({"name": name} if name else {}),
        }
        return self._request("POST", "/api/models", json=body)

    def identify(
        self,
        axis: str,
        datasets: Sequence[str],
        model: str = "static_pi",
        effects: Sequence[str] = ("hysteresis",),
        n_operators: int = 10,
        on_progress: ProgressCallback | None = None,
        name: str | None = None,
    ) -> dict:
        """Identify and wait (``name``: the model's label); returns the stored model. ApiError if the
        job did not succeed."""
        started = self.start_identify(axis, datasets, model, effects, n_operators, name)
        job = self.wait(started["job_id"], on_progress)
        if job["state"] != "succeeded":
            raise ApiError(500, f"identification job {job['id']} {job['state']}: {job['error'] or job['message']}")
        return self.model(job["result"]["model_id"])

    def model(self, model_id: str) -> dict:
        return self._request("GET", f"/api/models/{model_id}")

    def refine(self, model_id: str, **body) -> dict:
        """Refine (``add=``, ``remove=`` or ``effects=``, optional ``datasets=``) and wait; the new model."""
        job = self.wait(self._request("POST", f"/api/models/{model_id}/refine", json=body)["job_id"])
        if job["state"] != "succeeded":
            raise ApiError(500, f"refine job {job['id']} {job['state']}: {job['error'] or job['message']}")
        return self.model(job["result"]["model_id"])

    def model_report(self, model_id: str) -> str:
        """The model's self-contained HTML report (GET /api/models/{id}/report)."""
        return self._send("GET", f"/api/models/{model_id}/report", timeout=None).text

    def models(self) -> list[dict]:
        return self._request("GET", "/api/models")

    def label_model(self, model_id: str, **labels) -> dict:
        """Set some of a model's ``name``, ``tags`` (a list) and ``notes``; returns its record."""
        return self._request("PATCH", f"/api/models/{model_id}", json=labels)

    def delete_model(self, model_id: str, cascade: bool = False) -> dict:
        """Delete a model (ApiError 409 naming its children unless ``cascade``)."""
        return self._request("DELETE", f"/api/models/{model_id}", params={"cascade": cascade})

    def discover(
        self,
        model_id: str,
        allow_experiments: bool = False,
        max_steps: int | None = None,
        wait: bool = True,
        on_progress: ProgressCallback | None = None,
        continue_past_ambiguity: bool = False,
        max_experiments: int | None = None,
    ) -> dict:
        """Run the discovery loop from a model (POST /api/models/{id}/discover). With ``wait`` the
        finished job (its ``result``: steps, final_model_id, effects_found, remains, needed_experiment),
        ``on_progress`` called with the job at each step; else the queued job. It stops at an
        ambiguity it may not test (``stopped`` "needs_experiment") unless ``continue_past_ambiguity``;
        ``max_steps``, ``max_experiments``: model steps and experiments at most (the service's defaults,
        12 and 3, when None)."""
        body = {"allow_experiments": allow_experiments, "continue_past_ambiguity": continue_past_ambiguity}
        if max_steps is not None:
            body["max_steps"] = max_steps
        if max_experiments is not None:
            body["max_experiments"] = max_experiments
        started = self._request("POST", f"/api/models/{model_id}/discover", json=body)
        return self.wait(started["job_id"], on_progress) if wait else self.job(started["job_id"])

    def compare(self, model_id: str, dataset_id: str, max_points: int | None = None, arrays: bool = True) -> dict:
        """The metrics (over every sample) and, unless ``arrays`` is False, measured, predicted and
        residual arrays decimated by the service to at most ``max_points`` points each (default: the
        service's, 10 000, as ``dataset_data``; ``stride`` says by how much). For every sample pass
        ``max_points`` of at least the dataset's ``samples``."""
        params = {"dataset": dataset_id, "arrays": arrays, **({"max_points": max_points} if max_points else {})}
        return self._request("GET", f"/api/models/{model_id}/compare", params=params)

    # ------------------------------------------------------------------ plumbing
    def _request(self, method: str, path: str, **kwargs):
        return self._send(method, path, **kwargs).json()

    def _send(self, method: str, path: str, **kwargs) -> httpx.Response:
        response = self.http.request(method, path, **kwargs)
        if response.status_code >= 400:
            self._raise(response)
        return response

    @staticmethod
    def _raise(response: httpx.Response) -> None:
        try:
            field = response.json().get("field")
        except ValueError:
            field = None
        raise ApiError(response.status_code, _detail(response), field)


def _detail(response: httpx.Response) -> str:
    """The API's ``detail`` of an error answer, in words (the body's text if it is not JSON)."""
    try:
        return str(response.json().get("detail", response.text))
    except (ValueError, AttributeError):
        return response.text or response.reason_phrase
