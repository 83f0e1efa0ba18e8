"""NI-DAQmx DAQ driver. Hardware tests run only where the nidaqmx package, NI's driver library
and a device are present, and skip saying which is missing. The task choreography (AI armed on
ao/StartTrigger before AO starts, regeneration off, hold samples discarded, errors explained) is
checked everywhere against a recording stand-in for the nidaqmx package."""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest

from drivers import nidaq
from drivers.interfaces import DriverError, NotSupportedError


def test_error_codes_become_clear_messages():
    assert nidaq.explain_error(-200279, "Attempted to read samples that are no longer available.\nTask Name: _ai") == (
        "NI-DAQmx error -200279: the application is not keeping up with the hardware acquisition (AI buffer "
        "overflow): read larger blocks or lower the sample rate (Attempted to read samples that are no longer "
        "available.)"
    )
    assert "AO underflow" in nidaq.explain_error(-200290) and "AO underflow" in nidaq.explain_error(-200621)
    assert nidaq.explain_error(-1, "") == "NI-DAQmx error -1"


# ---------------------------------------------------------------------- a recording stand-in
class _Err(Exception):
    def __init__(self, message, error_code):
        super().__init__(message)
        self.error_code = error_code


def _fake_nidaqmx(log, coerced_rate=None, fail_read=None):
    enum = lambda name, *members: type(name, (), {m: f"{name}.{m}" for m in members})  # noqa: E731
    constants = types.SimpleNamespace(
        AcquisitionType=enum("AcquisitionType", "CONTINUOUS", "FINITE"),
        RegenerationMode=enum("RegenerationMode", "DONT_ALLOW_REGENERATION", "ALLOW_REGENERATION"),
        TerminalConfiguration=enum("TerminalConfiguration", "DIFF", "RSE"),
    )

    class Task:
        count = 0

        def __init__(self):
            Task.count += 1
            self.name = f"task{Task.count}"
            me = self
            self.ao_channels = types.SimpleNamespace(
                add_ao_voltage_chan=lambda ch, **kw: log.append((me.name, "ao", ch))
            )
            self.ai_channels = types.SimpleNamespace(
                add_ai_voltage_chan=lambda ch, **kw: log.append((me.name, "ai", ch, kw["terminal_config"]))
            )
            self.timing = types.SimpleNamespace(samp_clk_rate=None)
            self.timing.cfg_samp_clk_timing = lambda rate, **kw: (
                log.append((me.name, "clock", rate, kw.get("source", ""), kw["sample_mode"])),
                setattr(self.timing, "samp_clk_rate", coerced_rate or rate),
            )
            self.triggers = types.SimpleNamespace(
                start_trigger=types.SimpleNamespace(
                    cfg_dig_edge_start_trig=lambda src: log.append((me.name, "trigger", src))
                )
            )
            self.out_stream = types.SimpleNamespace(task=self, regen_mode=None)
            self.in_stream = types.SimpleNamespace(task=self)

        def start(self):
            log.append((self.name, "start", getattr(self.out_stream, "regen_mode", None)))

        def close(self):
            log.append((self.name, "close"))

        def write(self, data, auto_start=False):
            log.append((self.name, "write", list(data), auto_start))

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.close()

    class Writer:
        def __init__(self, stream, auto_start=False):
            self.stream = stream

        def write_many_sample(self, data, timeout=10.0):
            log.append((self.stream.task.name, "write_many", data.shape))

    class Reader:
        def __init__(self, stream):
            self.stream = stream

        def read_many_sample(self, data, number_of_samples_per_channel, timeout=10.0):
            if fail_read:
                raise _Err("Onboard device memory overflow.", fail_read)
            log.append((self.stream.task.name, "read_many", number_of_samples_per_channel))
            data[:] = np.arange(number_of_samples_per_channel)[None, :] + 10 * np.arange(data.shape[0])[:, None]

    module = types.ModuleType("nidaqmx")
    module.Task = Task
    module.constants = constants
    module.stream_writers = types.SimpleNamespace(AnalogMultiChannelWriter=Writer)
    module.stream_readers = types.SimpleNamespace(AnalogMultiChannelReader=Reader)
    return module


@pytest.fixture
def fake(monkeypatch):
    def install(**kw):
        log = []
        module = _fake_nidaqmx(log, **kw)
        for name, value in (
            ("nidaqmx", module),
            ("nidaqmx.constants", module.constants),
            ("nidaqmx.stream_readers", module.stream_readers),
            ("nidaqmx.stream_writers", module.stream_writers),
        ):
            monkeypatch.setitem(sys.modules, name, value)
        return log

    return install


def test_tasks_share_the_clock_and_ai_is_armed_before_ao(fake):
    log = fake(coerced_rate=19_999.6)
    daq = nidaq.NidaqDaq("Dev7", sample_rate_hz=20_000.0, hold_s=0.001)
    assert daq.sample_rate_hz == 19_999.6  # the coerced rate read back from samp_clk_rate
    assert daq.capabilities.point_by_point is False
    assert daq.capabilities.point_by_point_reason.startswith(
        "a USB X-Series DAQ has no hardware-timed single-point mode"
    )
    with pytest.raises(NotSupportedError, match="single-point"):
        daq.step([0.0, 0.0])
    assert log[:5] == [
        ("task1", "ao", "Dev7/ao0:1"),
        ("task2", "ai", "Dev7/ai0:3", "TerminalConfiguration.DIFF"),
        ("task1", "clock", 20_000.0, "", "AcquisitionType.CONTINUOUS"),
        ("task2", "clock", 20_000.0, "/Dev7/ao/SampleClock", "AcquisitionType.CONTINUOUS"),
        ("task2", "trigger", "/Dev7/ao/StartTrigger"),
    ]
    log.clear()
    ai = daq.write_read(np.zeros((100, 2)))
    hold = round(0.001 * 19_999.6)
    assert log == [
        ("task1", "write_many", (2, 100 + hold)),
        ("task2", "start", None),
        ("task1", "start", "RegenerationMode.DONT_ALLOW_REGENERATION"),
        ("task2", "read_many", 100),
    ]
    assert ai.shape == (100, 4) and ai[3, 1] == 13.0
    log.clear()
    daq.write_read(np.zeros((50, 2)))
    assert log == [("task1", "write_many", (2, 50 + hold)), ("task2", "read_many", hold), ("task2", "read_many", 50)]
    log.clear()
    daq.write_idle()
    assert ("task1", "close") in log and log[-2:] == [("task3", "write", [0.0, 0.0], True), ("task3", "close")]


def test_a_stream_error_idles_the_output_and_explains_itself(fake):
    log = fake(fail_read=-200279)
    daq = nidaq.NidaqDaq("Dev1", hold_s=0.001)
    with pytest.raises(
        DriverError,
        match="streaming a block: NI-DAQmx error -200279: the application is not "
        "keeping up with the hardware acquisition",
    ):
        daq.write_read(np.zeros((10, 2)))
    assert log[-2:] == [("task3", "write", [0.0, 0.0], True), ("task3", "close")]


def test_missing_package_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "nidaqmx", None)
    with pytest.raises(DriverError, match=r"pip install evc-bench\[nidaq\]"):
        nidaq.NidaqDaq()


# ---------------------------------------------------------------------- real hardware only
@pytest.fixture
def device():
    nidaqmx = pytest.importorskip(
        "nidaqmx", reason="the nidaqmx package is not installed (pip install evc-bench[nidaq])"
    )
    try:
        system = nidaqmx.system.System.local()
        _ = system.driver_version  # loading the driver library is the check
    except Exception as exc:  # noqa: BLE001 - DaqNotFoundError or an OSError from the loader
        pytest.skip(f"the NI-DAQmx driver library is not installed: {exc}")
    names = [d.name for d in system.devices]
    if not names:
        pytest.skip("NI-DAQmx is installed but no device is attached")
    return names[0]


def test_hardware_streams_blocks_and_returns_to_zero(device):
    daq = nidaq.NidaqDaq(device, sample_rate_hz=20_000.0)
    try:
        assert abs(daq.sample_rate_hz - 20_000.0) < 1.0
        ao = np.zeros((2000, 2))
        ao[:, 0] = np.linspace(0, 1, 2000)
        ai = daq.write_read(ao)
        assert ai.shape == (2000, 4) and np.all(np.isfinite(ai))
        daq.write_idle()
    finally:
        daq.close()


# ---------------------------------------------------------------------- the AO watchdog timer
@pytest.fixture
def fake_watchdog(fake, monkeypatch):
    """The stand-in plus nidaqmx.system.watchdog: a WatchdogTask that records its calls."""

    def install(**kw):
        log = fake(**kw)
        constants = sys.modules["nidaqmx.constants"]
        monkeypatch.setattr(
            constants,
            "WatchdogAOExpirState",
            types.SimpleNamespace(VOLTAGE="VOLTAGE", CURRENT="CURRENT"),
            raising=False,
        )

        class AOExpirationState:
            def __init__(self, physical_channel, expiration_state, output_type):
                self.args = (physical_channel, expiration_state, output_type)

        class WatchdogTask:
            expired = False

            def __init__(self, device_name, task_name="", timeout=10):
                log.append(("watchdog", "create", device_name, timeout))

            def cfg_watchdog_ao_expir_states(self, states):
                log.append(("watchdog", "ao_expir_states", [s.args for s in states]))

            def start(self):
                log.append(("watchdog", "start"))

            def reset_timer(self):
                log.append(("watchdog", "reset_timer"))

            def clear_expiration(self):
                log.append(("watchdog", "clear_expiration"))

            def stop(self):
                log.append(("watchdog", "stop"))

            def close(self):
                log.append(("watchdog", "close"))

        watchdog = types.SimpleNamespace(AOExpirationState=AOExpirationState, WatchdogTask=WatchdogTask)
        monkeypatch.setitem(sys.modules, "nidaqmx.system", types.SimpleNamespace(watchdog=watchdog))
        monkeypatch.setitem(sys.modules, "nidaqmx.system.watchdog", watchdog)
        return log, WatchdogTask

    return install


def test_the_ao_watchdog_is_armed_with_0v_expiration_states_and_petted(fake_watchdog):
    log, task_class = fake_watchdog()
    daq = nidaq.NidaqDaq("Dev3", ao_channels="ao0:1", sample_rate_hz=20_000.0)
    armed = daq.arm_watchdog(0.25)
    assert armed == {"device": "NI-DAQmx Dev3", "timeout_s": 0.25, "channels": ["Dev3/ao0", "Dev3/ao1"]}
    wd = [e for e in log if e[0] == "watchdog"]
    assert wd == [
        ("watchdog", "create", "Dev3", 0.25),
        ("watchdog", "ao_expir_states", [("Dev3/ao0", 0.0, "VOLTAGE"), ("Dev3/ao1", 0.0, "VOLTAGE")]),
        ("watchdog", "start"),
    ]
    assert daq.pet_watchdog() is None and log[-1] == ("watchdog", "reset_timer")
    task_class.expired = True  # the engine stopped petting: the device set its outputs to 0 V
    before = len(log)
    reason = daq.pet_watchdog()
    assert "Dev3" in reason and "expired" in reason and "0 V" in reason
    assert ("watchdog", "reset_timer") not in log[before:]  # an expired timer is reported, not petted
    daq.clear_watchdog()
    assert log[-1] == ("watchdog", "clear_expiration")
    daq.close()
    assert log[-2:] == [("watchdog", "stop"), ("watchdog", "close")]


def test_zero_ao_writes_0v_to_every_channel_from_any_process(fake):
    log = fake()
    assert nidaq.physical_channels("Dev1/ao0:1") == ["Dev1/ao0", "Dev1/ao1"]
    assert nidaq.physical_channels("Dev1/ao0, Dev2/ao2:3") == ["Dev1/ao0", "Dev2/ao2", "Dev2/ao3"]
    assert nidaq.zero_ao(device="Dev5", ao_channels="ao0:1", range_v=10.0) == "Dev5/ao0:1"
    name = log[0][0]
    assert log == [(name, "ao", "Dev5/ao0:1"), (name, "write", [0.0, 0.0], True), (name, "close")]
