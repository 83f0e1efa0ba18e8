"""Safe state (issue 9 §2, issue 6 §4): the watchdog trips a stalled loop to 0 V, SIGTERM drives a live
service to 0 V and cancels its job, the emergency stop pre-empts a sweep or a trajectory within one
control period, and a sensor loss during a trajectory trips the output to 0 V within one period.

Latencies are counted in emulated samples from the emulator's output log (drivers/emulated/output_log.py),
so they do not depend on the machine's speed; the watchdog's wall-clock bounds are generous."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest

from drivers.factory import open_bench
from drivers.watchdog import SafetyConfig, Watchdog
from service.http.app import create_app
from service.runtime.settings import Settings
from service.science.control.session import SCANNED_PID, Controller, track
from service.science.control.trajectory import Ellipse
from service.store import Store
from tests.support.api_client import authed_client, job_running, wait_job
from tests.support.live_server import ROOT, Server

FS = 20_000.0
PERIOD = 200  # samples per period of a 100 Hz trajectory at 20 kHz
BLOCK = 2000  # samples per buffered block of a sweep (its control period)
PID = {"kp_y": 1.0, "ki_y": 300.0, "kd_y": 0.01, "kp_z": 1.0, "ki_z": 300.0, "kd_z": 0.01, "tf_s": 2e-4}
ELLIPSE = {"y_range_um": [1, 6], "z_range_um": [1, 11], "frequency_hz": 100, "controller": {"pid": PID}}
LONG_SWEEP = {"axes": ["y"], "frequencies_hz": [0.5], "cycles": 100}  # 200 s of plan


class _FakeDaq:
    def __init__(self):
        self.idle_calls = 0

    def write_idle(self):
        self.idle_calls += 1


def test_watchdog_trips_a_stalled_loop_after_its_timeout_and_not_before():
    daq, trips = _FakeDaq(), []
    dog = Watchdog(daq, SafetyConfig(watchdog_periods=4, watchdog_min_s=0.05, watchdog_poll_s=0.002), trips.append)
    try:
        # 4 × 100 ms > 50 ms floor; a feed every 20 ms leaves 20× margin on a busy shared machine
        assert dog.arm(period_s=0.1, name="a test loop") == pytest.approx(0.4)
        for _ in range(10):  # fed every 20 ms for 0.2 s: no trip
            time.sleep(0.02)
            dog.feed(400)
        assert daq.idle_calls == 0 and trips == []
        deadline = time.monotonic() + 5
        while not trips and time.monotonic() < deadline:  # the loop stalls
            time.sleep(0.005)
        assert daq.idle_calls == 1 and len(trips) == 1
        trip = dog.last_trip
        assert trip["samples_fed"] == 4000 and trip["timeout_s"] == pytest.approx(0.4)
        assert 0.4 <= trip["stalled_s"] < 0.4 + 1.0
        assert "no sample written for" in trips[0] and "4 periods of 100.0 ms" in trips[0]
        assert "output set to 0 V" in trips[0] and trips[0].endswith("ms after the trip")
        assert SafetyConfig(watchdog_min_s=1.0).timeout_s(0.01) == 1.0  # the 1 s floor for fast loops
        assert SafetyConfig().timeout_s(2.0) == 8.0  # 4 periods of a slow one
    finally:
        dog.close()
    with pytest.raises(ValueError, match="safety.watchdog_periods"):
        SafetyConfig.from_config({"watchdog_periods": 0})


class _SlowIdleDaq:
    """A DAQ whose 0 V write takes a while, during which the stalled loop wakes up and feeds."""

    def __init__(self):
        self.idle_started, self.loop_fed = threading.Event(), threading.Event()

    def write_idle(self):
        self.idle_started.set()
        assert self.loop_fed.wait(10)


def test_a_trip_reports_the_gap_that_tripped_it_not_the_one_after_a_slow_zero_volt_write():
    daq, trips = _SlowIdleDaq(), []
    dog = Watchdog(daq, SafetyConfig(watchdog_periods=4, watchdog_min_s=0.05, watchdog_poll_s=0.002), trips.append)

    def loop():  # feeds once, stalls until the trip writes 0 V, then feeds 7 times
        dog.feed(100)
        assert daq.idle_started.wait(10)
        for _ in range(7):
            dog.feed(10)
        daq.loop_fed.set()

    try:
        timeout_s = dog.arm(period_s=0.01, name="a test loop")
        worker = threading.Thread(target=loop)
        worker.start()
        worker.join(20)
        deadline = time.monotonic() + 10
        while not trips and time.monotonic() < deadline:
            time.sleep(0.005)
        trip = dog.last_trip
        assert len(trips) == 1 and trip["timeout_s"] == pytest.approx(0.05) == timeout_s
        assert trip["stalled_s"] >= trip["timeout_s"]  # the old report said ~0 s here
        assert trip["samples_fed"] == 100 and trip["fed_during_zero_v"] == 70
        assert trip["zero_v_s"] >= 0 and trip["zero_v_at_monotonic_s"] >= trip["at_monotonic_s"]
        assert f"no sample written for {trip['stalled_s']:.2f} s" in trips[0]
    finally:
        dog.close()


def test_a_stalled_tracking_loop_is_tripped_to_zero_volts_by_the_watchdog():
    bench = open_bench(
        "default", seed=3, overrides={"safety": {"watchdog_min_s": 0.2}, "faults": {"loop_stall": {"after_s": 0.25}}}
    )
    try:
        result, rec, ref = track(bench, Ellipse((1, 6), (1, 11), 0.0, 100.0, 40), Controller(pid=SCANNED_PID))
        assert result["tripped"].startswith("watchdog: no sample written for")
        assert "max(4 periods of 10.0 ms, 0.2 s)" in result["tripped"]
        trip = bench.watchdog.last_trip
        # the gap the watchdog reports is at least its limit (how much more depends on how busy the
        # machine is when its thread wakes: a figure, not a bound)
        assert trip["timeout_s"] == 0.2 and trip["stalled_s"] >= 0.2
        # the stall began at the start of the period holding t = 0.25 s; nothing was written after it
        assert rec.samples == int(0.25 * FS) - int(0.05 * FS)  # session time minus the 50 ms settle
        last = bench.parts.world.output_log.last()
        assert last["event"] == "idle" and last["daq_ao_v"] == {"y": 0.0, "z": 0.0}
        assert max(abs(v) for v in last["amplifier_v"].values()) < 0.05
    finally:
        bench.close()


@pytest.fixture
def service(tmp_path, request):
    """The app on the default bench; a test's ``safety`` marker adds a [safety] table."""
    bench = "default"
    marker = request.node.get_closest_marker("safety")
    if marker is not None:
        bench = str(tmp_path / "bench.toml")
        Path(bench).write_text(
            f'extends = "{ROOT / "fixtures" / "benches" / "default.toml"}"\n[safety]\n'
            + "".join(f"{k} = {v}\n" for k, v in marker.kwargs.items())
        )
    app = create_app(Settings(data_dir=tmp_path / "data", bench=bench, seed=1))
    with authed_client(app) as http:
        world = app.state.bench.parts.world
        stops: list[float] = []
        original = app.state.bench.request_stop

        def spy(reason="stopped on request"):  # the emulated time at which the stop flag went up
            stops.append(world.time_s)
            original(reason)

        app.state.bench.request_stop = spy
        yield app, http, stops


def _first_zero_after(app, t_s: float) -> tuple[dict, list[dict]]:
    """The first 0 V write at or after emulated time ``t_s`` and the drive entries between them."""
    entries = app.state.bench.parts.world.output_log.entries()
    idle = next(e for e in entries if e["event"] == "idle" and e["zero_from_t_s"] >= t_s - 1e-9)
    between = [
        e for e in entries if e["event"] in ("block", "period") and t_s + 1e-6 < e["t_s"] <= idle["zero_from_t_s"]
    ]
    return idle, between


def _assert_stopped(app, http, job_id, stops, max_samples: int) -> dict:
    job = wait_job(http, job_id)
    assert job["state"] == "cancelled" and job["message"].startswith("emergency stop: "), job
    idle, _ = _first_zero_after(app, stops[0])
    latency = round((idle["zero_from_t_s"] - stops[0]) * FS)
    assert 0 <= latency <= max_samples, latency
    assert idle["daq_ao_v"] == {"y": 0.0, "z": 0.0} and max(abs(v) for v in idle["amplifier_v"].values()) < 0.05
    ds = http.get(f"/api/datasets/{job['result']['dataset_id']}").json()
    assert ds["partial"] is True and ds["partial_reason"] == "emergency stop" and ds["samples"] > 0
    return job


def test_emergency_stop_preempts_a_sweep_within_one_block(service):
    app, http, stops = service
    job_id = http.post("/api/sweeps", json=LONG_SWEEP).json()["job_id"]
    queued_id = http.post("/api/sweeps", json=LONG_SWEEP).json()["job_id"]
    wait_job(http, job_id, until=job_running(0.01))
    answer = http.post("/api/bench/stop")
    assert answer.status_code == 200 and answer.json()["cancelled_job_id"] == job_id
    assert answer.json()["cancelled_queued_job_ids"] == [queued_id]  # the bench stays still
    queued = http.get(f"/api/jobs/{queued_id}").json()
    assert queued["state"] == "cancelled" and queued["message"] == "emergency stop" and queued["started_at"] is None
    assert answer.json()["loop_answered"] is True
    assert max(abs(v) for v in answer.json()["output_v"].values()) < 0.05
    _assert_stopped(app, http, job_id, stops, max_samples=BLOCK)
    assert app.state.bench.describe()["safety"]["running"] is False


def test_emergency_stop_preempts_a_point_by_point_trajectory_within_one_period(service):
    app, http, stops = service
    started = http.post("/api/trajectories", json={**ELLIPSE, "cycles": 3000})
    assert started.status_code == 202
    job_id = started.json()["job_id"]
    wait_job(http, job_id, until=job_running(0.01))
    answer = http.post("/api/bench/stop")
    assert answer.status_code == 200 and answer.json()["cancelled_job_id"] == job_id
    job = _assert_stopped(app, http, job_id, stops, max_samples=PERIOD)
    assert job["result"]["stopped"] is True and job["error"] is None


def test_sensor_loss_during_a_trajectory_trips_to_zero_volts_within_one_period(service):
    app, http, _ = service
    posted = http.post("/api/admin/faults", json={"fault": "sensor_dropout", "axis": "z", "after_s": 0.3})
    assert posted.status_code == 201
    job_id = http.post("/api/trajectories", json={**ELLIPSE, "cycles": 60}).json()["job_id"]
    job = wait_job(http, job_id)
    assert job["state"] == "failed" and "gauge z: dropout (injected at t=0.30 s)" in job["error"], job
    (fault,) = http.get("/api/admin/faults").json()["faults"]
    idle, between = _first_zero_after(app, fault["world_t_s"])
    assert round((idle["zero_from_t_s"] - fault["world_t_s"]) * FS) <= PERIOD and between == []
    assert idle["daq_ao_v"] == {"y": 0.0, "z": 0.0}
    ds = http.get(f"/api/datasets/{job['result']['dataset_id']}").json()
    assert ds["partial"] is True and "gauge z: dropout" in ds["partial_reason"]
    assert ds["samples"] == int(0.3 * FS) - int(0.05 * FS) + PERIOD  # to the end of the fault's period


@pytest.mark.realtime
def test_sigterm_drives_a_live_service_to_zero_volts_and_cancels_its_job(tmp_path: Path):
    log = tmp_path / "output.jsonl"
    bench = tmp_path / "sigterm.toml"
    bench.write_text(
        f'extends = "{ROOT / "fixtures" / "benches" / "default.toml"}"\n[emulator]\noutput_log = "{log}"\n'
    )
    data_dir = tmp_path / "data"
    server = Server(data_dir, tmp_path / "server.log", bench=str(bench))
    import httpx

    with httpx.Client(base_url=server.url, timeout=30, headers=server.headers) as http:
        job_id = http.post("/api/trajectories", json={**ELLIPSE, "cycles": 5000}).json()["job_id"]
        wait_job(http, job_id, until=job_running(0.01))
    assert server.stop(), (tmp_path / "server.log").read_text()[-3000:]
    entries = [json.loads(line) for line in log.read_text().splitlines()]
    drive = [i for i, e in enumerate(entries) if e["event"] == "period"]
    after = entries[drive[-1] + 1 :]
    assert after[0]["event"] == "idle" and after[0]["daq_ao_v"] == {"y": 0.0, "z": 0.0}
    assert round((after[0]["zero_from_t_s"] - entries[drive[-1]]["t_s"]) * FS) <= PERIOD
    assert entries[-1]["event"] == "close" and max(abs(v) for v in entries[-1]["amplifier_v"].values()) < 0.05
    store = Store(Settings(data_dir=data_dir).resolved_database_url, data_dir)
    try:
        job = store.get_job(job_id)
        assert job["state"] == "cancelled" and job["message"].startswith("stopped by SIGTERM: "), job
        ds = store.get_dataset(job["result"]["dataset_id"])
        assert ds["partial"] is True and ds["partial_reason"] == "stopped by SIGTERM" and ds["samples"] > 0
    finally:
        store.close()


@pytest.mark.safety(stop_wait_s=0.1, watchdog_min_s=10.0)
def test_emergency_stop_of_a_stalled_loop_writes_zero_volts_itself(service):
    """The loop does not answer (stalled in a write): the stop writes 0 V from the request's thread
    after [safety] stop_wait_s (0.1 s here), long before the watchdog (10 s here), and the job is cancelled."""
    app, http, stops = service
    assert http.post("/api/admin/faults", json={"fault": "loop_stall", "after_s": 0.2}).status_code == 201
    job_id = http.post("/api/sweeps", json=LONG_SWEEP).json()["job_id"]
    deadline = time.monotonic() + 60
    while http.get("/api/admin/faults").json()["faults"][0]["state"] != "fired":
        assert time.monotonic() < deadline
        time.sleep(0.01)
    answer = http.post("/api/bench/stop").json()
    assert answer["loop_answered"] is False and answer["cancelled_job_id"] == job_id
    job = wait_job(http, job_id)
    assert job["state"] == "cancelled" and job["message"].startswith("emergency stop: "), job
    assert app.state.bench.watchdog.last_trip is None  # the stop came first
    idle, between = _first_zero_after(app, stops[0])
    assert between == [] and idle["daq_ao_v"] == {"y": 0.0, "z": 0.0}
    assert round(idle["zero_from_t_s"] * FS) == round(0.2 * FS)  # nothing was written after the stall began


def test_a_stop_during_the_ilc_response_measurement_ends_the_whole_experiment():
    """ILC runs two sessions (response measurement, then tracking); a stop in the first must not let
    the second drive the bench."""
    from contextlib import contextmanager

    from service.science.control.loop import StopRequested

    bench = open_bench("default", seed=4)
    sessions = []
    original = bench.session

    @contextmanager
    def session(*args, **kwargs):
        with original(*args, **kwargs) as s:
            sessions.append(bench.parts.world.time_s)
            bench.request_stop("emergency stop")  # as if POST /api/bench/stop arrived now
            yield s

    bench.session = session
    try:
        with pytest.raises(StopRequested, match="emergency stop"):
            track(bench, Ellipse((1, 6), (1, 11), 0.0, 100.0, 20), Controller(pid=SCANNED_PID, ilc=True))
        assert len(sessions) == 1  # the tracking session never opened
        drive = [e for e in bench.parts.world.output_log.entries() if e["event"] in ("block", "period")]
        assert all(max(abs(v) for v in e["daq_ao_v"].values()) == 0.0 for e in drive)  # settle only: 0 V
        assert bench.parts.world.output_log.last()["daq_ao_v"] == {"y": 0.0, "z": 0.0}
    finally:
        del bench.session
        bench.close()


def test_sigint_handler_reaches_zero_volts_before_uvicorn_shuts_down(service):
    """safe_shutdown.install wraps uvicorn's handler: 0 V and the job cancelled first, then uvicorn's."""
    import signal

    from service.runtime.safe_shutdown import install

    app, http, stops = service
    calls = []

    class FakeServer:
        def handle_exit(self, sig, frame):
            calls.append((sig, app.state.bench.describe()["safety"]["running"]))

    server = FakeServer()
    install(server, app)
    job_id = http.post("/api/sweeps", json=LONG_SWEEP).json()["job_id"]
    wait_job(http, job_id, until=job_running(0.01))
    server.handle_exit(signal.SIGINT, None)
    assert calls == [(signal.SIGINT, False)]  # uvicorn's handler ran after the loop had stopped
    job = wait_job(http, job_id)
    assert job["state"] == "cancelled" and job["message"].startswith("stopped by SIGINT: "), job
    idle, between = _first_zero_after(app, stops[0])
    # a stop that lands between the flag check and the write lets that one block out: one control period
    assert len(between) <= 1 and round((idle["zero_from_t_s"] - stops[0]) * FS) <= BLOCK


@pytest.mark.realtime
def test_sigterm_to_the_process_group_leaves_zero_volts_and_no_failure_in_the_log(tmp_path: Path):
    """A SIGTERM to `make run`'s process group reaches the bench engine too, which leaves at 0 V on its
    own, often before the web process's handler asks it to stop. The service still shuts down cleanly,
    the outputs end at 0 V, and the log says what happened without a "safe state … failed" traceback."""
    log = tmp_path / "output.jsonl"
    bench = tmp_path / "group.toml"
    bench.write_text(
        f'extends = "{ROOT / "fixtures" / "benches" / "default.toml"}"\n[emulator]\noutput_log = "{log}"\n'
    )
    server = Server(tmp_path / "data", tmp_path / "server.log", bench=str(bench), own_group=True)
    import httpx

    with httpx.Client(base_url=server.url, timeout=30, headers=server.headers) as http:
        job_id = http.post("/api/trajectories", json={**ELLIPSE, "cycles": 5000}).json()["job_id"]
        wait_job(http, job_id, until=job_running(0.01))
    assert server.stop(group=True), (tmp_path / "server.log").read_text()[-3000:]
    text = (tmp_path / "server.log").read_text()
    assert "safe state on signal" not in text and "Traceback" not in text, text[-3000:]
    assert "stopped by SIGTERM" in text
    entries = [json.loads(line) for line in log.read_text().splitlines()]
    last_drive = max(i for i, e in enumerate(entries) if e["event"] == "period")
    assert any(
        e["event"] in ("idle", "close") and max(abs(v) for v in e.get("daq_ao_v", {"y": 0.0}).values()) == 0.0
        for e in entries[last_drive + 1 :]
    ), entries[last_drive + 1 :]
    assert entries[-1]["event"] == "close" and max(abs(v) for v in entries[-1]["amplifier_v"].values()) < 0.05


def test_a_signal_that_reached_the_engine_first_is_logged_without_a_traceback(caplog):
    """A SIGTERM to `make run`'s process group reaches the bench engine too, which leaves at 0 V on
    its own: the web process's handler then finds the engine gone. It says so in one warning (no
    "failed" traceback) and still hands over to uvicorn's handler."""
    import logging
    import signal
    from types import SimpleNamespace

    from service.runtime.engine import EngineUnavailable
    from service.runtime.safe_shutdown import install

    class GoneBench:
        def stop(self, reason):
            raise EngineUnavailable("the bench engine process has exited (code 143)")

    calls = []
    server = SimpleNamespace(handle_exit=lambda sig, frame: calls.append(sig))
    install(server, SimpleNamespace(state=SimpleNamespace(bench=GoneBench(), jobs=None)))
    with caplog.at_level(logging.WARNING, logger="evcbench.safety"):
        server.handle_exit(signal.SIGTERM, None)
    assert calls == [signal.SIGTERM]
    (record,) = caplog.records
    assert record.levelno == logging.WARNING and record.exc_info is None
    assert (
        "stopped by SIGTERM without a bench engine: the bench engine process has exited (code 143)"
        in record.getMessage()
    )
