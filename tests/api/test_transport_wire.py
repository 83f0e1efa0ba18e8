"""The bench with its parts on real transports (serial pty + CAN virtual bus) against the emulator:
the same sweep as in-process within noise, and each transport fault stops the run cleanly."""

from __future__ import annotations

import re
import time

import numpy as np
import pytest

from drivers.composed import check_transport
from drivers.emulated import kernels as K
from drivers.factory import open_bench
from drivers.record import RunInterrupted
from service.frontends.client import Client
from service.http.app import create_app
from service.runtime.settings import Settings
from tests.support.api_client import authed_client, job_running, wait_job

FS = 20_000.0
BLOCK = 1000


def _served(tmp_path, bench):
    app = create_app(Settings(data_dir=tmp_path / bench, bench=bench, seed=3))
    http = authed_client(app)
    return app, http, Client(http=http)


def test_a_sweep_over_serial_and_can_matches_the_in_process_emulator(tmp_path):
    plan = {"axes": ["y", "z"], "frequencies_hz": [10, 50], "cycles": 2, "settle_s": 0.05}
    data = {}
    for bench in ("default", "default_wire"):
        app, http, api = _served(tmp_path, bench)
        with http:
            assert app.state.bench.parts.backend.startswith("composed" if "wire" in bench else "emulated")
            job = api.sweep(**plan)
            assert job["state"] == "succeeded", job
            data[bench] = app.state.store.load_arrays(job["result"]["dataset_id"])
            described = api.bench()
            if "wire" in bench:
                assert described["sensors"]["y"]["ok"] and described["amplifiers"]["y"]["fault"] is False
                responder = app.state.bench.parts.daq.emulators["serial"]
                assert any(cmd == b"xvoltage?" for cmd, _ in responder.transcript)
    a, b = data["default"], data["default_wire"]
    assert set(a) == set(b) and len(a["x_y_um"]) == len(b["x_y_um"]) > 5_000
    np.testing.assert_array_equal(a["u_y_v"], b["u_y_v"])
    for axis in ("y", "z"):
        x_a, x_b = np.asarray(a[f"x_{axis}_um"]), np.asarray(b[f"x_{axis}_um"])
        assert np.ptp(x_a) > 5.0  # a real loop was measured ...
        assert np.max(np.abs(x_b - x_a)) <= 0.0005 + 1e-9  # ... and the wire adds only 1 nm LSB rounding,
        assert np.std(x_b - x_a) < 0.3 * 0.003  # well below the 3 nm gauge noise
        np.testing.assert_allclose(x_b * 1000, np.round(x_b * 1000), atol=1e-6)  # positions came as int32 nm
        assert not np.allclose(x_a * 1000, np.round(x_a * 1000), atol=1e-6)


def _wire_bench():
    return open_bench("default_wire", seed=2)


def _run_with_fault(bench, inject):
    u = 60.0 * (1 - np.cos(2 * np.pi * 20.0 * np.arange(6 * BLOCK) / FS))

    def on_block(record, fraction):
        if record.samples == BLOCK:
            inject()

    with pytest.raises(RunInterrupted) as err:
        bench.run({"y": u, "z": u}, FS, block_samples=BLOCK, on_block=on_block)
    world = bench.parts.world
    assert np.all(np.abs(world.sa[:, K.S_VP]) < 0.05)  # the output is at 0 V
    record = err.value.record
    assert record.partial and record.reason == err.value.reason
    assert 0 < record.samples < 6 * BLOCK and np.all(np.isfinite(record.x_um["y"]))
    np.testing.assert_array_equal(record.u_cmd_v["y"], u[: record.samples])
    return err.value.reason, record


@pytest.mark.parametrize(
    "fault, expected",
    [
        ("garble", r"amplifier y: serial: MDT693B on /dev/pts/\d+: garbled reply to 'xvoltage\?'"),
        ("silent", r"amplifier y: serial: MDT693B on /dev/pts/\d+: no reply to 'xvoltage\?' within 0.2 s"),
        ("unplug", r"amplifier y: serial: MDT693B: serial port /dev/pts/\d+ lost"),
    ],
)
def test_serial_faults_stop_the_run_with_the_reason_and_keep_the_data(fault, expected):
    bench = _wire_bench()
    responder = bench.parts.daq.emulators["serial"]
    try:

        def inject():
            if fault == "unplug":
                responder.unplug()
            else:
                responder.mode = fault

        reason, record = _run_with_fault(bench, inject)
        assert record.samples == 2 * BLOCK  # the block in flight when the link failed is kept too

        assert re.search(expected, reason), reason
    finally:
        bench.close()


def test_can_bus_off_stops_the_run_with_the_reason_and_keeps_the_data():
    bench = _wire_bench()
    nodes = bench.parts.daq.emulators["can"]
    try:
        t0 = time.monotonic()
        reason, record = _run_with_fault(bench, lambda: nodes.inject("bus_off"))
        assert time.monotonic() - t0 < 60  # a hang guard (the driver's timeouts are ~1 s), not a figure
        assert record.samples == BLOCK  # the block whose positions never arrived is dropped
        assert reason.startswith("daq: CAN virtual:evc-emulated-") and "bus-off" in reason
        assert "bus-off" in bench.parts.sensors["y"].status().reason
    finally:
        bench.close()


def test_a_gauge_dropout_over_can_stops_the_run():
    bench = _wire_bench()
    try:
        reason, record = _run_with_fault(bench, lambda: bench.parts.world.inject_fault("sensor_dropout", "z"))
        assert reason == "sensor z: gauge z (CAN node 2): dropout, signal lost (run stopped at t=0.10 s)"
        assert record.samples == 2 * BLOCK
    finally:
        bench.close()


def test_transport_table_is_checked():
    with pytest.raises(ValueError, match="transport.amplifier.baud: unknown key"):
        check_transport({"amplifier": {"baud": 9600}})
    with pytest.raises(ValueError, match="transport.sensors.node_ids"):
        check_transport({"sensors": {"kind": "can", "node_ids": {"y": 1, "z": 1}}})
    with pytest.raises(ValueError, match="emulated parts need daq = 'emulated'"):
        check_transport({"daq": "nidaq", "amplifier": {"kind": "serial", "port": "emulated"}})
    with pytest.raises(ValueError, match="transport.daq"):
        open_bench("default", overrides={"transport": {"daq": "labjack"}})


def test_gauges_on_ai_with_can_for_configuration_and_faults():
    wire = open_bench("default_wire", seed=2, overrides={"transport.sensors.positions": "ai"})
    local = open_bench("default", seed=2)
    u = 60.0 * (1 - np.cos(2 * np.pi * 20.0 * np.arange(4 * BLOCK) / FS))
    try:
        a = local.run({"y": u, "z": u}, FS, block_samples=BLOCK)
        b = wire.run({"y": u, "z": u}, FS, block_samples=BLOCK)
        for axis in ("y", "z"):  # same world, same AI: identical up to float rounding of the scale
            np.testing.assert_allclose(b.x_um[axis], a.x_um[axis], atol=1e-12)
        nodes = wire.parts.daq.emulators["can"]
        reason, record = _run_with_fault(wire, lambda: nodes.inject("bus_off"))
        assert reason.startswith("sensor y: gauge y: CAN virtual:evc-emulated-")
        assert reason.endswith("bus-off (error frame 0x40) (run stopped at t=0.10 s)")
        assert record.samples == 2 * BLOCK
    finally:
        wire.close()
        local.close()


def test_the_service_fails_a_sweep_whose_port_is_unplugged_and_keeps_its_samples(tmp_path):
    app, http, api = _served(tmp_path, "default_wire")
    with http:
        started = api.start_sweep(axes=["y"], frequencies_hz=[1.0], cycles=20)
        wait_job(api.job, started["job_id"], until=job_running(0.02), timeout_s=30, poll_s=0.01)
        app.state.bench.parts.daq.emulators["serial"].unplug()
        job = wait_job(api.job, started["job_id"], timeout_s=30, poll_s=0.01)
        # the unplug races the per-block status queries: whichever axis asks first reports it
        assert job["state"] == "failed" and re.match(
            r"amplifier [yz]: serial: MDT693B: serial port \S+ lost", job["error"]
        ), job["error"]
        ds = api.dataset(job["result"]["dataset_id"])
        assert ds["partial"] and "lost" in ds["partial_reason"] and 0 < ds["samples"] < started["samples"]
        assert np.all(np.abs(app.state.bench.parts.world.sa[:, K.S_VP]) < 0.05)
