"""Issue 21's lab for real: three ``evcbench serve`` processes (the default bench and the creep and
dynamics variants) on ONE PostgreSQL database, each with its own data dir and a 0.5 s heartbeat.
They sweep at the same time over REST; every dataset lands with its bench id, every job ran on its
own bench; any service lists all of it and filters by bench; one service's token works on all; a
killed service shows offline on the others (its datasets stay listed), a stopped one ``stopped``;
a second service that claims a live bench id is refused before it recovers anything, and the
crashed bench's service starts again on its own id at once."""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest

from tests.support.api_client import wait_job
from tests.support.lab_services import HEARTBEAT_S, LAB_BENCHES, fresh_database, lab_services, start_service

pytestmark = [pytest.mark.postgres, pytest.mark.slow]

#: One frequency, few cycles: a short sweep (0.4 s of drive) on every bench.
SWEEP = {"axes": ["y"], "frequencies_hz": [10], "cycles": 4}


def _lab_view(server, bench_id: str) -> dict:
    benches = httpx.get(f"{server.url}/api/lab/benches", headers=server.headers, timeout=30).json()["benches"]
    return next(b for b in benches if b["id"] == bench_id)


def _until(server, bench_id: str, condition, timeout_s: float = 60.0) -> dict:
    """Poll ``server``'s lab view until ``condition(entry of bench_id)`` holds; the entry (AssertionError
    with the last entry if it never does)."""
    deadline = time.monotonic() + timeout_s
    while True:
        entry = _lab_view(server, bench_id)
        if condition(entry) or time.monotonic() > deadline:
            assert condition(entry), entry
            return entry
        time.sleep(HEARTBEAT_S / 2)


def test_three_services_on_one_postgres(tmp_path, postgres_url):
    database = fresh_database(postgres_url)
    with lab_services(tmp_path, database) as lab:
        clients = {b: httpx.Client(base_url=f"{s.url}/api", headers=s.headers, timeout=60) for b, s in lab.items()}
        try:
            # every service sweeps at the same time
            with ThreadPoolExecutor(len(lab)) as pool:
                queued = dict(zip(lab, pool.map(lambda b: clients[b].post("/sweeps", json=SWEEP).json(), lab)))
                jobs = dict(
                    zip(
                        lab,
                        pool.map(
                            lambda b: wait_job(
                                lambda i: clients[b].get(f"/jobs/{i}").json(), queued[b]["job_id"], timeout_s=300
                            ),
                            lab,
                        ),
                    )
                )
            datasets = {}
            for bench, job in jobs.items():
                assert job["state"] == "succeeded" and job["bench_id"] == bench, job
                ds = clients[bench].get(f"/datasets/{job['result']['dataset_id']}").json()
                # recorded on its own bench: the bench's configuration as that service opened it
                assert ds["bench_id"] == bench and ds["job_id"] == job["id"]
                assert ds["config"]["backend"] == f"emulated:{bench}" and ds["config"]["parameters"]["name"] == bench
                datasets[bench] = ds["id"]
            creep = clients["creep"].get(f"/datasets/{datasets['creep']}").json()["config"]["parameters"]
            assert creep["axes"]["y"]["piezo"]["creep"]["rate_per_decade"] == 0.03

            # any service shows the whole lab, and one bench's rows on request
            for client in clients.values():
                listed = {d["id"]: d["bench_id"] for d in client.get("/datasets").json()}
                assert listed == {datasets[b]: b for b in LAB_BENCHES}
                assert [d["id"] for d in client.get("/datasets", params={"bench_id": "creep"}).json()] == [
                    datasets["creep"]
                ]
                assert {j["id"]: j["bench_id"] for j in client.get("/jobs").json()} == {
                    jobs[b]["id"]: b for b in LAB_BENCHES
                }
            for bench in LAB_BENCHES:  # the next heartbeat after the sweep says idle
                _until(lab["default"], bench, lambda e: e["state"] == "idle")
            view = clients["default"].get("/lab/benches").json()
            assert view["this_bench_id"] == "default"
            assert {
                b["id"]: (b["online"], b["state"], b["datasets"], b["running_job_id"]) for b in view["benches"]
            } == {b: (True, "idle", 1, None) for b in LAB_BENCHES}
            assert {b["id"]: b["url"] for b in view["benches"]} == {b: s.url for b, s in lab.items()}
            # one lab, one token table: the default service's bootstrap token works on the creep service
            assert httpx.get(f"{lab['creep'].url}/api/bench", headers=lab["default"].headers).status_code == 200
            # a service never cancels another bench's job (here a finished one: nothing to do, 202 as ever)
            assert clients["default"].delete(f"/jobs/{jobs['creep']['id']}").json()["state"] == "succeeded"

            # a second service claiming the live id 'creep' is refused before it touches anything
            with pytest.raises(RuntimeError, match="bench id 'creep' is held by a running service") as refused:
                start_service(tmp_path / "intruder", database, "creep")
            assert "exited with 2" in str(refused.value) and "Traceback" not in str(refused.value)

            # kill -9 the dynamics service: offline on the others after 3 silent heartbeats
            lab["dynamics"].proc.kill()
            lab["dynamics"].proc.wait(timeout=60)
            gone = _until(lab["default"], "dynamics", lambda e: not e["online"])
            assert gone["state"] == "idle" and gone["heartbeat_age_s"] > 3 * HEARTBEAT_S  # its last word
            assert gone["datasets"] == 1
            assert clients["default"].get(f"/datasets/{datasets['dynamics']}").json()["bench_id"] == "dynamics"
            assert datasets["dynamics"] in {d["id"] for d in clients["creep"].get("/datasets").json()}

            # a clean stop says so at once
            assert lab["creep"].stop()
            stopped = _lab_view(lab["default"], "creep")
            assert (stopped["online"], stopped["state"], stopped["running_job_id"]) == (False, "stopped", None)

            # the crashed bench's service starts again on its own id (same host, its process gone)
            again = start_service(tmp_path, database, "dynamics")
            try:
                back = _until(lab["default"], "dynamics", lambda e: e["online"] and e["url"] == again.url)
                assert back["state"] == "idle" and back["url"] == again.url and back["datasets"] == 1
            finally:
                assert again.stop()
        finally:
            for client in clients.values():
                client.close()
