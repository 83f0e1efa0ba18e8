"""NI-DAQmx DAQ (USB X Series such as the USB-6361) through the ``nidaqmx`` package.

Optional: ``pip install evc-bench[nidaq]`` plus NI's NI-DAQmx driver. Importing this module
never needs either; opening a ``NidaqDaq`` does, and says so when they are missing.

Streaming: one continuous AO task and one continuous AI task on the same sample clock. The AI
task is armed first, triggered by ``/<dev>/ao/StartTrigger``, so sample k of AI is taken at
AO update k. Regeneration is off: every AO sample is written by the host exactly once.

Block hand-off: ``write_read`` must return the AI of the block it wrote, so when it returns the
AO buffer would be empty and the next write would come too late (an underflow). Each block is
therefore followed by copies of its last value for ``hold_s`` (default 50 ms), which keep the
generation going during the host's turnaround; their AI samples are read and discarded. The
actuator sees a short hold between blocks; a turnaround longer than the hold is an underflow
(-200290), reported as such. The Bench's per-block status checks (serial, CAN) are part of
the turnaround. USB X Series devices have no hardware-timed single-point mode.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from drivers.interfaces import DaqCapabilities, DriverError, LimitError, NotSupportedError

POINT_BY_POINT_REASON = (
    "a USB X-Series DAQ has no hardware-timed single-point mode; use buffered streaming (write_read)"
)
ERRORS = {
    -200279: "the application is not keeping up with the hardware acquisition (AI buffer overflow): "
    "read larger blocks or lower the sample rate",
    -200290: "AO underflow: the host did not write the next block before the buffer emptied; "
    "increase hold_s or the block size",
    -200621: "AO underflow: onboard memory emptied before the host wrote more data",
    -200018: "the DAC conversion was attempted before data was available (underflow)",
    -200284: "some or all requested samples have not yet been acquired (read timed out)",
    -200077: "a requested value is not supported for this property (sample rate, range or terminal)",
    -200220: "device identifier is invalid: check the device name in NI MAX",
    -201003: "device cannot be accessed: it was removed or is reserved by another application",
    -50103: "the specified resource is reserved by another task",
}


def explain_error(code: int | None, message: str = "") -> str:
    """A clear message for a DAQmx status code (the driver's own text kept after it)."""
    known = ERRORS.get(code)
    head = f"NI-DAQmx error {code}: {known}" if known else f"NI-DAQmx error {code}"
    first = (message or "").strip().splitlines()[0] if message and message.strip() else ""
    return f"{head} ({first})" if first else head


def physical_channels(spec: str) -> list[str]:
    """``"Dev1/ao0:1"`` → ``["Dev1/ao0", "Dev1/ao1"]`` (a comma list of such ranges too)."""
    out = []
    for part in spec.split(","):
        head, _, last = part.strip().rpartition(":")
        if not head:
            out.append(part.strip())
            continue
        stem = head.rstrip("0123456789")
        first = int(head[len(stem) :])
        out.extend(f"{stem}{k}" for k in range(first, int(last) + 1))
    return out


def zero_ao(device: str = "Dev1", ao_channels: str = "ao0:1", range_v: float = 10.0, **_other) -> str:
    """0 V on ``device``'s AO channels from any process (an on-demand task, closed at once): what the
    supervisor writes after the engine died (a dead process's tasks are released). Returns them."""
    nidaqmx = _nidaqmx()[0]
    phys = f"{device}/{ao_channels}"
    try:
        with nidaqmx.Task() as task:
            task.ao_channels.add_ao_voltage_chan(phys, min_val=-float(range_v), max_val=float(range_v))
            task.write([0.0] * len(physical_channels(phys)), auto_start=True)
    except Exception as exc:  # noqa: BLE001
        raise NidaqDaq._driver_error(exc, "driving the output to 0 V") from exc
    return phys


def _nidaqmx():
    try:
        import nidaqmx
        from nidaqmx import constants, stream_readers, stream_writers
    except ImportError as exc:
        raise DriverError("the nidaqmx package is not installed: pip install evc-bench[nidaq]") from exc
    return nidaqmx, constants, stream_readers, stream_writers


class NidaqDaq:
    """Two AO (``ao0:1``), ``ai_count`` AI (``ai0:<n-1>``, gauges first) on ``device``; volts at the terminals."""

    def __init__(
        self,
        device: str = "Dev1",
        ao_channels: str = "ao0:1",
        ai_channels: str = "ai0:3",
        ai_count: int = 4,
        range_v: float = 10.0,
        timebase_hz: float = 100e6,
        max_sample_rate_hz: float = 250e3,
        sample_rate_hz: float = 20e3,
        hold_s: float = 0.05,
        terminal_config: str = "DIFF",
        timeout_s: float = 2.0,
    ):
        self._mx = _nidaqmx()
        self.device, self.range_v, self.timeout_s, self.hold_s = device, float(range_v), float(timeout_s), float(hold_s)
        self._ao_phys, self._ai_phys = f"{device}/{ao_channels}", f"{device}/{ai_channels}"
        self._terminal = terminal_config
        self.capabilities = DaqCapabilities(
            buffered=True,
            point_by_point=False,
            ao_channels=2,
            ai_channels=int(ai_count),
            ao_range_v=(-self.range_v, self.range_v),
            ai_range_v=(-self.range_v, self.range_v),
            resolution_bits=16,
            timebase_hz=float(timebase_hz),
            max_sample_rate_hz=float(max_sample_rate_hz),
            point_by_point_reason=POINT_BY_POINT_REASON,
        )
        self._rate = 0.0
        self._ao = self._ai = None
        self._watchdog = None  # nidaqmx.system.WatchdogTask once armed
        self._pending_discard = 0
        self._closed = False
        self.configure(sample_rate_hz)

    @property
    def sample_rate_hz(self) -> float:
        return self._rate

    def configure(self, sample_rate_hz: float) -> float:
        """Create the AO/AI tasks on a clock of ``sample_rate_hz``; return the coerced rate the
        driver reports (``task.timing.samp_clk_rate``)."""
        rate = float(sample_rate_hz)
        if not np.isfinite(rate) or rate <= 0 or rate > self.capabilities.max_sample_rate_hz:
            raise LimitError(
                f"sample rate {sample_rate_hz!r} Hz is outside 0..{self.capabilities.max_sample_rate_hz:g} Hz"
            )
        if self._ao is not None and rate == self._requested:
            return self._rate
        self._stop_tasks()
        nidaqmx, c, _, _ = self._mx
        self._requested = rate
        buffer = max(int(2 * rate), 10_000)  # two seconds of host buffer per channel (a block + hold must fit)
        try:
            ao, ai = nidaqmx.Task(), nidaqmx.Task()
            self._ao, self._ai = ao, ai
            ao.ao_channels.add_ao_voltage_chan(self._ao_phys, min_val=-self.range_v, max_val=self.range_v)
            terminal = getattr(c.TerminalConfiguration, self._terminal)
            ai.ai_channels.add_ai_voltage_chan(
                self._ai_phys, terminal_config=terminal, min_val=-self.range_v, max_val=self.range_v
            )
            ao.timing.cfg_samp_clk_timing(rate, sample_mode=c.AcquisitionType.CONTINUOUS, samps_per_chan=buffer)
            ai.timing.cfg_samp_clk_timing(
                rate,
                source=f"/{self.device}/ao/SampleClock",
                sample_mode=c.AcquisitionType.CONTINUOUS,
                samps_per_chan=4 * buffer,
            )
            ao.out_stream.regen_mode = c.RegenerationMode.DONT_ALLOW_REGENERATION
            ai.triggers.start_trigger.cfg_dig_edge_start_trig(f"/{self.device}/ao/StartTrigger")
            self._rate = float(ao.timing.samp_clk_rate)
        except Exception as exc:  # noqa: BLE001
            self._stop_tasks()
            raise self._driver_error(exc, "configuring the sample clock") from exc
        self._running = False
        return self._rate

    def write_read(self, ao_daq_v: np.ndarray) -> np.ndarray:
        """Write an (n, 2) block (+ the hold), return the (n, ai_channels) AI of the block."""
        ao = np.asarray(ao_daq_v, dtype=np.float64)
        if ao.ndim != 2 or ao.shape[1] != 2:
            raise ValueError(f"AO block must have shape (n, 2), got {ao.shape}")
        if not np.all(np.isfinite(ao)) or (ao.size and np.max(np.abs(ao)) > self.range_v):
            raise LimitError(f"AO data is not finite or outside ±{self.range_v:g} V; nothing was written")
        if self._ao is None:
            self.configure(self._requested)
        _, _, readers, writers = self._mx
        hold = max(1, int(round(self.hold_s * self._rate)))
        data = np.ascontiguousarray(np.vstack([ao, np.repeat(ao[-1:], hold, axis=0)]).T)
        n = ao.shape[0]
        try:
            writers.AnalogMultiChannelWriter(self._ao.out_stream, auto_start=False).write_many_sample(
                data, timeout=self.timeout_s
            )
            if not self._running:
                self._ai.start()  # armed: waits for ao/StartTrigger
                self._ao.start()
                self._running = True
            reader = readers.AnalogMultiChannelReader(self._ai.in_stream)
            if self._pending_discard:
                junk = np.empty((self.capabilities.ai_channels, self._pending_discard))
                reader.read_many_sample(
                    junk, number_of_samples_per_channel=self._pending_discard, timeout=self.timeout_s
                )
            out = np.empty((self.capabilities.ai_channels, n))
            reader.read_many_sample(out, number_of_samples_per_channel=n, timeout=self.timeout_s + n / self._rate)
            self._pending_discard = hold
        except Exception as exc:  # noqa: BLE001
            self.write_idle()
            raise self._driver_error(exc, "streaming a block") from exc
        return out.T

    def step(self, ao_daq_v: Sequence[float]) -> np.ndarray:
        raise NotSupportedError(POINT_BY_POINT_REASON)

    def write_idle(self) -> None:
        """Stop streaming and drive both AO channels to 0 V with an on-demand write."""
        self._stop_tasks()
        if self._closed:
            return
        nidaqmx = self._mx[0]
        try:
            with nidaqmx.Task() as task:
                task.ao_channels.add_ao_voltage_chan(self._ao_phys, min_val=-self.range_v, max_val=self.range_v)
                task.write([0.0, 0.0], auto_start=True)
        except Exception as exc:  # noqa: BLE001
            raise self._driver_error(exc, "driving the output to 0 V") from exc

    # ------------------------------------------------------------------ the AO watchdog timer
    def arm_watchdog(self, timeout_s: float) -> dict:
        """Arm the device's watchdog timer: if ``pet_watchdog`` is not called within ``timeout_s``
        (s), the device itself sets both AO channels to their expiration state, 0 V
        (DAQmxCfgWatchdogAOExpirStates; X Series). Returns what was armed."""
        from nidaqmx.constants import WatchdogAOExpirState
        from nidaqmx.system.watchdog import AOExpirationState, WatchdogTask

        self._close_watchdog()
        channels = physical_channels(self._ao_phys)
        try:
            task = WatchdogTask(self.device, timeout=float(timeout_s))
            task.cfg_watchdog_ao_expir_states(
                [
                    AOExpirationState(
                        physical_channel=ch, expiration_state=0.0, output_type=WatchdogAOExpirState.VOLTAGE
                    )
                    for ch in channels
                ]
            )
            task.start()
        except Exception as exc:  # noqa: BLE001
            raise self._driver_error(exc, "arming the AO watchdog") from exc
        self._watchdog = task
        return {"device": f"NI-DAQmx {self.device}", "timeout_s": float(timeout_s), "channels": channels}

    def pet_watchdog(self) -> str | None:
        """Reset the watchdog timer; its expiry in words if it had expired (outputs held at 0 V)."""
        task = self._watchdog
        if task is None:
            return None
        try:
            if task.expired:
                return f"NI-DAQmx {self.device}: AO watchdog expired; the device set the outputs to 0 V"
            task.reset_timer()
        except Exception as exc:  # noqa: BLE001
            raise self._driver_error(exc, "petting the AO watchdog") from exc
        return None

    def clear_watchdog(self) -> None:
        """After an expiry: the AO channels follow writes again (the timer keeps running)."""
        if self._watchdog is not None:
            try:
                self._watchdog.clear_expiration()
            except Exception as exc:  # noqa: BLE001
                raise self._driver_error(exc, "clearing the AO watchdog") from exc

    def _close_watchdog(self) -> None:
        task, self._watchdog = self._watchdog, None
        if task is not None:
            try:
                task.stop()
                task.close()
            except Exception:  # noqa: BLE001 - a removed device cannot be stopped
                pass

    def close(self) -> None:
        if not self._closed:
            try:
                self.write_idle()
            finally:
                self._close_watchdog()
                self._closed = True

    def _stop_tasks(self) -> None:
        for task in (self._ai, self._ao):
            if task is not None:
                try:
                    task.close()
                except Exception:  # noqa: BLE001 - a removed device cannot be stopped
                    pass
        self._ao = self._ai = None
        self._running = False
        self._pending_discard = 0

    @staticmethod
    def _driver_error(exc: Exception, doing: str) -> DriverError:
        code = getattr(exc, "error_code", None)
        return DriverError(f"{doing}: {explain_error(code, str(exc))}")
