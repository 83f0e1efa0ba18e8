"""Running a reference through the bench under FF + PID + ILC, period by period.

Point-by-point: each period runs in the compiled runner (kernels.point_by_point_runner) through the
DAQ's compiled stepping hook, PID every sample; Python only sees period boundaries (ILC update,
fault check, progress). Buffered: one period per DAQ block with two blocks queued, so a
correction learned from period j first reaches period j+2; no per-sample feedback.
Every run is a ``Bench.session``: the watchdog is fed once per period, the stop flag is polled by the
compiled runner (every ≤ 50 samples) and between blocks, and every trip, stop or end leaves the DAQ at 0 V.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from drivers.bench import Bench, BenchSession
from drivers.interfaces import DriverError
from service.science.control import kernels as CK
from service.science.control.damping import ModeDamping
from service.science.control.ilc import HarmonicILC
from service.science.control.safety import stepping_hook
from service.science.control.trajectory import Reference
from service.science.fitting.metrics import rms

QUEUED_BLOCKS = 2  # buffered streaming: blocks in flight ahead of the one being measured
SETTLE_S = 0.05  # 0 V held before each run so earlier motion has died out


class StopRequested(RuntimeError):
    """A run that other runs depend on (the ILC's response measurement) was stopped on request;
    nothing may drive the bench after it in the same experiment. ``reason`` says who stopped it."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class PIDGains(NamedTuple):
    """Paper eq. 19 gains: kp V/µm, ki V/(µm·s), kd V·s/µm; derivative filter time constant tf_s;
    optionally a PPF section that damps the axis's flexure mode (service.science.control.damping).
    A tuple too, (kp, ki, kd, tf_s, damping), as the frequency responses take gains."""

    kp: float
    ki: float
    kd: float = 0.0
    tf_s: float = 1e-4
    damping: ModeDamping | None = None

    def row(self, sample_rate_hz: float) -> list[float]:
        """The compiled loop's parameter row (service.science.control.kernels: pid_p)."""
        section = self.damping.biquad(sample_rate_hz) if self.damping is not None else (0.0,) * 5
        return [self.kp, self.ki, self.kd, self.tf_s, 1.0, *section]


@dataclass
class TrackRecord:
    """What a tracking run measured: x_um and u_v (n, 2), the reference, per-period RMS error (µm)."""

    x_um: np.ndarray
    u_v: np.ndarray
    ref_um: np.ndarray
    samples: int
    error_per_period_um: list[float] = field(default_factory=list)
    tripped: str | None = None
    stopped: bool = False
    stop_reason: str | None = None
    ilc_stop_reason: str | None = None


def trip_limits(
    bench: Bench,
    ref: Reference,
    error_fraction: float = 1.0,
    error_floor_um: float = 0.5,
    trip_samples: int | None = None,
) -> np.ndarray:
    """Per axis (error limit µm, samples over it to trip, sensor range µm)."""
    pp = np.ptp(ref.x_um, axis=0)
    n = trip_samples or max(5, ref.period // 20)
    return np.array(
        [
            [error_fraction * pp[i] + error_floor_um, n, 0.98 * bench.parts.sensors[a].range_um[1]]
            for i, a in enumerate(bench.axes)
        ],
        dtype=float,
    )


def compile_runner(bench: Bench):
    """(runner, world args, take_noise) of ``bench``'s per-sample loop, compiled by a zero-length call,
    or None without a compiled stepping hook. The bench engine calls it as it starts, so that no
    run compiles (seconds that hold the GIL, during which even the stop port would wait)."""
    hook = stepping_hook(bench)
    if hook is None:
        return None
    step_fn, args, take_noise = hook
    runner = CK.point_by_point_runner(step_fn, getattr(bench.parts.daq, "stepping_sources", None))
    noise, n0 = take_noise(0)
    empty = np.zeros((0, 2))
    runner(
        args,
        noise,
        n0,
        empty,
        empty.copy(),
        np.zeros((2, CK.NPID)),
        np.zeros((2, CK.NPS)),
        np.zeros(2),
        np.zeros((2, CK.NL)),
        np.zeros((2, CK.NT)),
        np.zeros(2),
        np.zeros(2),
        np.zeros(2),
        1.0,
        empty.copy(),
        empty.copy(),
        np.zeros((1, 4)),
        np.zeros((1, 10)),
        np.zeros(1, np.uint8),
    )
    return runner, args, take_noise


class Tracker:
    """Runs ``ref`` with feedforward ``u_ff_v`` (n, 2), optional per-axis PID and optional ILC."""

    def __init__(
        self,
        bench: Bench,
        ref: Reference,
        u_ff_v: np.ndarray | None,
        mode: str = "point_by_point",
        pid: dict[str, PIDGains] | None = None,
        ilc: HarmonicILC | None = None,
        trip: np.ndarray | None = None,
    ):
        self.bench, self.ref, self.mode, self.ilc = bench, ref, mode, ilc
        n = ref.x_um.shape[0]
        self.u_ff = np.zeros((n, 2)) if u_ff_v is None else np.ascontiguousarray(u_ff_v, dtype=float)
        self.pid_p = np.zeros((2, CK.NPID))
        for i, axis in enumerate(bench.axes):
            if pid and pid.get(axis) is not None:
                self.pid_p[i] = pid[axis].row(ref.sample_rate_hz)
        self.fs = ref.sample_rate_hz
        self.lim = np.array(
            [
                [
                    bench.limits[a].v_min_v,
                    bench.limits[a].v_max_v,
                    bench.limits[a].max_rate_v_per_s / self.fs,
                    bench.parts.amplifiers[a].gain_v_per_v,
                ]
                for a in bench.axes
            ]
        )
        self.trip = trip_limits(bench, ref) if trip is None else trip
        self._ilc_limits = (self.lim[:, CK.L_VMIN].copy(), self.lim[:, CK.L_VMAX].copy())
        self._ilc_applied: dict[int, np.ndarray] = {}  # period → the ILC correction its command carried
        self.um_per_v = np.array([bench.parts.sensors[a].scale_um_per_v for a in bench.axes])

    def _command(self, p: int) -> np.ndarray:
        s = slice(p * self.ref.period, (p + 1) * self.ref.period)
        u = self.u_ff[s].copy()
        if self.ilc is not None:
            u += self.ref.envelope[s, None] * self.ilc.u_v
            self._ilc_applied[p] = self.ilc.u_v  # the ILC publishes a new array per update
        return u

    def _learn(self, p: int, rec: TrackRecord) -> None:
        applied = self._ilc_applied.pop(p, None)
        steady = self.ref.ramp_periods <= p < self.ref.ramp_periods + self.ref.cycles
        if not steady:
            return
        s = slice(p * self.ref.period, (p + 1) * self.ref.period)
        err = self.ref.x_um[s] - rec.x_um[s]
        if self.ilc is not None:
            base = self.u_ff[self.ref.steady][: self.ref.period]
            self.ilc.update(err, base_v=base, limits_v=self._ilc_limits, applied_v=applied)
            rec.error_per_period_um.append(self.ilc.history_um[-1])
        else:
            rec.error_per_period_um.append(rms(err))

    def run(
        self, on_period: Callable[[int, TrackRecord], None] | None = None, should_stop: Callable[[], bool] | None = None
    ) -> TrackRecord:
        """Run every period; returns the record (``tripped`` says why it ended early)."""
        n = self.ref.x_um.shape[0]
        rec = TrackRecord(x_um=np.full((n, 2), np.nan), u_v=np.zeros((n, 2)), ref_um=self.ref.x_um, samples=0)
        # compile before the watchdog is armed (compiling can take seconds on a fresh numba cache)
        compiled = self._compiled_runner() if self.mode == "point_by_point" else None
        CK.watch_block(self.ref.x_um[:0], rec.x_um[:0], self.trip, np.zeros(2))
        with self.bench.session(period_s=self.ref.period / self.fs, name="a tracking run") as session:
            self.bench.configure(self.fs)
            try:
                self._settle(session)
                self.bench.live.begin(self.fs, "tracking")
                if self.mode == "point_by_point":
                    self._run_pbp(compiled, rec, on_period, should_stop, session)
                else:
                    self._run_buffered(rec, on_period, should_stop, session)
            except DriverError as exc:  # a transport or the DAQ failed mid-run: keep what was measured
                if not self._interrupted(rec, session):  # unless a stop or the watchdog abandoned the write
                    rec.tripped = f"daq: {exc}"
        if self.ilc is not None:
            rec.ilc_stop_reason = self.ilc.stop_reason
        return rec

    def _settle(self, session: BenchSession, settle_s: float = SETTLE_S) -> None:
        """Hold 0 V for ``settle_s`` so a previous run's motion has died out before this one starts."""
        daq = self.bench.parts.daq
        daq.write_idle()
        n = int(settle_s * self.fs)
        daq.write_read(np.zeros((n, daq.capabilities.ao_channels)))
        session.feed(n)

    def _interrupted(self, rec: TrackRecord, session: BenchSession) -> bool:
        why = session.interrupted()
        if why and self.bench.tripped:
            rec.tripped = why
        elif why:
            rec.stopped, rec.stop_reason = True, why
        return why is not None

    def _trip_reason(self, status: int, rec: TrackRecord) -> str:
        """The watch's trip in words, naming the device fault behind it when there is one (an amplifier
        that tripped to 0 V makes the tracking error diverge)."""
        fault = self.bench.fault_reason()
        cause = f"{CK.TRIP_REASONS[status]} ({fault})" if fault else CK.TRIP_REASONS[status]
        return f"{cause} at {rec.samples / self.fs * 1e3:.1f} ms; output set to 0 V"

    def _end_period(self, p, rec, on_period, should_stop, session) -> bool:
        session.feed(self.ref.period)
        s = slice(p * self.ref.period, rec.samples)
        self.bench.live.push_columns(rec.u_v[s], rec.x_um[s])  # u_v, x_um columns are in bench.axes order
        reason = self.bench.fault_reason()
        if reason:
            rec.tripped = f"{reason} (tripped at t={rec.samples / self.fs:.2f} s)"
            return True
        if self._interrupted(rec, session):
            return True
        self._learn(p, rec)
        if on_period is not None:
            on_period(p, rec)
        if should_stop is not None and should_stop():
            rec.stopped, rec.stop_reason = True, self.bench.interrupt_reason() or "stopped on request"
            return True
        return False

    def _compiled_runner(self):
        """(runner, world args, take_noise), compiled by a zero-length call (compiling takes seconds,
        which must not count as a stalled loop once the watchdog is armed)."""
        compiled = compile_runner(self.bench)
        if compiled is None:
            raise RuntimeError("point_by_point needs the DAQ's compiled stepping hook")
        return compiled

    def _run_pbp(self, compiled, rec, on_period, should_stop, session) -> None:
        runner, args, take_noise = compiled
        # the world the hook steps is driven by one thread at a time (a watchdog's 0 V waits a period)
        driving = getattr(self.bench.parts.daq, "drive_lock", None) or nullcontext()
        pid_s = np.zeros((2, CK.NPS))
        u_last, y_last, over = np.zeros(2), np.zeros(2), np.zeros(2)
        ai, diag = np.zeros((1, 4)), np.zeros((1, 10))
        N = self.ref.period
        for p in range(self.ref.periods):
            s = slice(p * N, (p + 1) * N)
            noise, n0 = take_noise(N)
            x, u = np.zeros((N, 2)), np.zeros((N, 2))
            with driving:
                done, status = runner(
                    args,
                    noise,
                    n0,
                    self.ref.x_um[s],
                    self._command(p),
                    self.pid_p,
                    pid_s,
                    u_last,
                    self.lim,
                    self.trip,
                    over,
                    self.um_per_v,
                    y_last,
                    1.0 / self.fs,
                    x,
                    u,
                    ai,
                    diag,
                    session.stop_flag,
                )
            rec.x_um[s][:done], rec.u_v[s][:done] = x[:done], u[:done]
            rec.samples = p * N + done
            if status == CK.STOPPED:
                self.bench.parts.daq.write_idle()
                self._interrupted(rec, session)
                return
            if status != CK.OK:
                self.bench.parts.daq.write_idle()
                rec.tripped = self._trip_reason(status, rec)
                return
            if self._end_period(p, rec, on_period, should_stop, session):
                return

    def _run_buffered(self, rec, on_period, should_stop, session) -> None:
        daq, parts, N = self.bench.parts.daq, self.bench.parts, self.ref.period
        queue = [self._command(p) for p in range(min(QUEUED_BLOCKS, self.ref.periods))]
        prev = np.zeros(2)
        over = np.zeros(2)
        for p in range(self.ref.periods):
            s = slice(p * N, (p + 1) * N)
            if self._interrupted(rec, session):
                return
            cmd = queue.pop(0)
            ao = np.zeros((N, daq.capabilities.ao_channels))
            for i, axis in enumerate(self.bench.axes):
                block = self.bench.clamp_block(axis, cmd[:, i], prev[i], self.fs)
                prev[i] = block[-1]
                rec.u_v[s, i] = block
                ao[:, parts.ao_channel[axis]] = block / parts.amplifiers[axis].gain_v_per_v
            ai = daq.write_read(ao)
            for i, axis in enumerate(self.bench.axes):
                rec.x_um[s, i] = ai[:, parts.ai_channel[axis]] * parts.sensors[axis].scale_um_per_v
            done, status = CK.watch_block(self.ref.x_um[s], rec.x_um[s], self.trip, over)
            rec.samples = p * N + (done if status != CK.OK else N)
            if status != CK.OK:
                daq.write_idle()
                rec.tripped = self._trip_reason(status, rec)
                return
            if self._end_period(p, rec, on_period, should_stop, session):
                return
            if p + QUEUED_BLOCKS < self.ref.periods:
                queue.append(self._command(p + QUEUED_BLOCKS))
