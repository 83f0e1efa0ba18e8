"""Fuzzing (issue 9 §5): schemathesis generates requests from the app's OpenAPI spec.

Every operation gets ``MAX_EXAMPLES`` generated requests (valid and invalid bodies, queries and
path values), in-process over ASGI against the emulated bench. Each response must be below 500,
and each 4xx must carry a reason: the project's error JSON, ``{"detail": "<words>", ...}``.
Admin endpoints (``/api/admin/*``: fault injection and the like) are left out, since they exist to
disturb the service. A job a generated request starts (a sweep, a trajectory, an identification)
is cancelled at once, so generated work does not pile up on the bench.

Bounded: the whole file runs in about 25 s on a 2-core machine: some 2800 requests
(docs/explanation/architecture.md, "What keeps the real-time loop on time under load").
The requests are the same every run; ``EVCBENCH_FUZZ_RANDOM=1`` draws new ones to hunt for more.
"""

from __future__ import annotations

import collections
import json
import os
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, settings

from service.http.app import create_app
from service.runtime.settings import Settings
from tests.support.api_client import bearer

#: About a minute; one worker runs the whole file (its module app, and the summary it writes at the end).
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("fuzz")]

MAX_EXAMPLES = 40
SUMMARY = Path(__file__).resolve().parents[1] / "artifacts" / "fuzz_summary.json"
#: (method path) -> Counter of status codes, written to SUMMARY at the end (the figures of a run)
TALLY: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
#: Reproducible by default (the same requests every run); EVCBENCH_FUZZ_RANDOM=1 explores new ones.
DERANDOMIZE = os.environ.get("EVCBENCH_FUZZ_RANDOM", "") in ("", "0")


@pytest.fixture(scope="module")
def fuzz_app(tmp_path_factory):
    """The app on a fresh store and the default emulated bench, its lifespan running."""
    from schemathesis.python import asgi

    app = create_app(Settings(data_dir=tmp_path_factory.mktemp("fuzz-store"), bench="default", seed=1))
    with asgi.get_client(app) as client:  # starts the lifespan: store, bench, job manager
        app.state.fuzz_client = client
        yield app
    asgi.shutdown_lifespans()  # stops the jobs, parks the bench at 0 V and closes the store
    total = collections.Counter()
    for counts in TALLY.values():
        total.update(counts)
    SUMMARY.parent.mkdir(exist_ok=True)
    SUMMARY.write_text(
        json.dumps(
            {
                "requests": sum(total.values()),
                "method_paths": len(TALLY),
                "status_codes": dict(sorted(total.items())),
                "per_operation": {k: dict(sorted(v.items())) for k, v in sorted(TALLY.items())},
            },
            indent=1,
        )
    )


@pytest.fixture(scope="module")
def auth_headers(fuzz_app) -> dict[str, str]:
    """Headers every fuzzed call carries: an operate-scope token (the admin endpoints are excluded),
    so the fuzzer reaches the handlers instead of stopping at 401."""
    from service.security import auth

    return bearer(auth.issue(fuzz_app.state.store, "fuzz", "operate", "cli")[0])


# The spec of an app that is never started (building the spec needs no store and no bench).
schema = schemathesis.openapi.from_dict(create_app().openapi()).exclude(path_regex=r"^/api/admin(/|$)")


@schema.parametrize()
@settings(
    max_examples=MAX_EXAMPLES,
    deadline=None,
    derandomize=DERANDOMIZE,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much, HealthCheck.data_too_large],
)
def test_no_server_errors_and_every_4xx_says_why(case, fuzz_app, auth_headers):
    response = case.call(
        base_url="http://testserver", session=fuzz_app.state.fuzz_client, headers=auth_headers, timeout=30
    )
    _cancel_started_job(fuzz_app, response)
    TALLY[f"{case.method} {case.path}"][response.status_code] += 1
    where = f"{case.method} {case.formatted_path} query={case.query} body={str(case.body)[:300]}"
    assert response.status_code < 500, f"{where} -> {response.status_code}: {response.text[:500]}"
    if 400 <= response.status_code < 500:
        try:
            body = response.json()
        except ValueError:
            pytest.fail(f"{where} -> {response.status_code} without a JSON body: {response.text[:200]}")
        detail = body.get("detail") if isinstance(body, dict) else None
        assert isinstance(detail, str) and detail.strip(), f"{where} -> {response.status_code} without a reason: {body}"


def _cancel_started_job(app, response) -> None:
    if response.status_code != 202:
        return
    try:
        job_id = response.json().get("job_id")
    except (ValueError, AttributeError):
        return
    if job_id:
        app.state.jobs.cancel(job_id)
