"""A real service process (``evcbench serve`` under uvicorn, on a free port): sweep → identify →
compare through service/frontends/client.py and through the CLI, then SIGTERM during a sweep and a restart
that finds every dataset and model unchanged (checksums)."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

from service.frontends.client import Client
from tests.support.api_client import job_running, wait_job
from tests.support.live_server import Server, evcbench
from tests.support.realdata import MODEL_VI_DO as REAL

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.realtime  # a live `evcbench serve`


def _cli(server: Server, *args: str) -> subprocess.CompletedProcess:
    """``evcbench`` as a lab user runs it next to the service: the token comes from <data dir>/admin.token."""
    result = evcbench(server, *args, timeout_s=300)
    assert result.returncode == 0, f"evcbench {' '.join(args)} failed:\n{result.stdout}\n{result.stderr}"
    return result


def _state(api: Client, data_dir: Path) -> dict:
    datasets = [api.dataset(d["id"]) for d in api.datasets()]
    files = {d["id"]: hashlib.sha256((data_dir / d["file"]).read_bytes()).hexdigest() for d in datasets}
    assert files == {d["id"]: d["sha256"] for d in datasets}  # every file matches its stored checksum
    return {"datasets": datasets, "models": api.models(), "files": files}


@pytest.fixture
def data_dir(tmp_path):
    return tmp_path / "var"


def test_real_process_sweep_identify_compare_cli_and_restart(data_dir, tmp_path):
    log = tmp_path / "server.log"
    server = Server(data_dir, log)
    try:
        # a new user learns from the start-up lines where the dashboard's token is
        assert f"API token: paste the content of {server.data_dir / 'admin.token'}" in log.read_text()
        with Client(server.url, token=server.token) as api:
            # --- the Python client
            events = []
            job = api.sweep(axes=["y"], frequencies_hz=[10, 50, 100], cycles=3, on_progress=events.append)
            assert job["state"] == "succeeded" and events[-1]["progress"] == 1.0
            dataset_id = job["result"]["dataset_id"]
            model = api.identify("y", [dataset_id], model="static_pi")
            compared = api.compare(model["id"], dataset_id, max_points=500)
            assert compared["metrics"]["overall"]["fit_pct"] > 90
            assert len(compared["metrics"]["per_block"]) == 3 and len(compared["x_predicted_um"]) <= 500

            # --- the CLI, as a user runs it
            out = _cli(server, "sweep", "--axes", "y", "--frequencies", "20,80", "--cycles", "3", "--wait")
            # into a pipe the progress is a line per message, each with its percentage, ending at 100 %
            assert out.stderr.splitlines()[-1] == "100.0 % succeeded: done" and "\r" not in out.stderr
            cli_dataset = out.stdout.split("dataset ")[1].split()[0]
            assert api.dataset(cli_dataset)["blocks"][1]["frequency_hz"] == 80.0
            out = _cli(server, "identify", "--axis", "y", "--datasets", f"{dataset_id},{cli_dataset}")
            cli_model = out.stdout.split("model ")[1].split()[0]
            assert sorted(api.model(cli_model)["datasets"]) == sorted([dataset_id, cli_dataset])
            out = _cli(server, "compare", cli_model, "--dataset", cli_dataset)
            assert "heldout_rms_um" in out.stdout and "overall: RMS" in out.stdout
            metrics = json.loads(_cli(server, "compare", cli_model, "--dataset", cli_dataset, "--json").stdout)
            assert [b["frequency_hz"] for b in metrics["per_block"]] == [20.0, 80.0]
            assert cli_model in _cli(server, "models").stdout
            assert "identify" in _cli(server, "jobs").stdout
            assert "nothing was latched" in _cli(server, "reset").stdout
            stopped = json.loads(_cli(server, "stop", "--json").stdout)
            assert stopped["cancelled_job_id"] is None and all(abs(v) < 0.05 for v in stopped["output_v"].values())
            assert stopped["door"] == "stop port"  # the CLI presses the engine's own port
            refused = subprocess.run(
                [sys.executable, "-m", "service.frontends.cli", "jobs", "--url", server.url, "--token", "evc_wrong"],
                cwd=ROOT,
                capture_output=True,
                text=True,
                timeout=120,
            )
            assert refused.returncode == 2 and "error 401 [authorization]: unknown API token" in refused.stderr
            out = _cli(
                server,
                "import",
                str(REAL),
                "--columns",
                '{"u":0,"x":4}',
                "--sample-rate-hz",
                "200",
                "--axis",
                "y",
                "--delimiter",
                "whitespace",
            )
            assert "8027 samples at 200 Hz" in out.stdout

            # --- SIGTERM while a sweep runs: the partial record is kept
            long = api.start_sweep(axes=["y"], frequencies_hz=[0.5], cycles=100)
            wait_job(api.job, long["job_id"], until=job_running(0.01), timeout_s=60)
            before = _state(api, data_dir)
        assert server.stop()
    finally:
        if server.proc.poll() is None:
            server.proc.kill()

    server = Server(data_dir, log)
    try:
        with Client(server.url, token=server.token) as api:
            after = _state(api, data_dir)
            partial = [d for d in after["datasets"] if d["partial"]]
            assert len(partial) == 1 and partial[0]["job_id"] == long["job_id"]
            assert [d for d in after["datasets"] if not d["partial"]] == before["datasets"]
            assert {k: v for k, v in after["files"].items() if k != partial[0]["id"]} == before["files"]
            assert after["models"] == before["models"]
            assert api.job(long["job_id"])["state"] == "cancelled"
            again = api.compare(model["id"], dataset_id, max_points=500)
            assert again["metrics"] == compared["metrics"] and again["x_predicted_um"] == compared["x_predicted_um"]
        assert server.stop()
    finally:
        if server.proc.poll() is None:
            server.proc.kill()


def test_evcbench_stop_needs_nothing_of_a_frozen_web_process(tmp_path):
    """The web process stopped dead (SIGSTOP) mid-sweep: `evcbench stop` on its machine still drives the
    bench to 0 V through the engine's stop port, which it finds in <data dir>/stop_port.json."""
    import signal

    server = Server(tmp_path / "var", tmp_path / "server.log", bench="default_realtime")
    try:
        announced = json.loads((server.data_dir / "stop_port.json").read_text())
        assert announced["service_port"] == server.port and announced["stop_port"] > 0
        with Client(server.url, token=server.token) as api:
            job = api.start_sweep(axes=["y", "z"], frequencies_hz=[1], cycles=30)
            wait_job(api.job, job["job_id"], until=job_running(0.02), timeout_s=60)
            server.proc.send_signal(signal.SIGSTOP)
            try:
                stopped = json.loads(_cli(server, "stop", "--json").stdout)
            finally:
                server.proc.send_signal(signal.SIGCONT)
            assert stopped["door"] == "stop port" and stopped["cancelled_job_id"] == job["job_id"]
            assert all(abs(v) < 0.05 for v in stopped["output_v"].values())
            done = wait_job(api.job, job["job_id"], timeout_s=60)
            assert done["state"] == "cancelled" and "emergency stop" in done["message"]
        assert server.stop()
        assert not (server.data_dir / "stop_port.json").exists()  # a clean shut-down takes it back
    finally:
        if server.proc.poll() is None:
            server.proc.kill()
