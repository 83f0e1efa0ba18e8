"""Characterisation plans: dataclasses that become per-axis waveforms (actuator volts) and a block table.

Waveforms (each starts and ends at 0 V, with raised-cosine ramps to and from ``v_min``):
- ``sine``: biased sine v_min + (v_max − v_min)(1 − cos 2πft)/2 per frequency, ``cycles`` each,
  ``settle_s`` at v_min between frequencies. One block per frequency.
- ``step``: step-hold for creep: ramp to each level, hold ``hold_s``, ramp back, hold ``hold_s``.
- ``chirp``: biased linear chirp from ``f_start_hz`` to ``f_stop_hz`` over about ``duration_s``.
- ``multisine``: Schroeder-phased sum of sines at ``frequencies_hz`` (integer multiples of the
  lowest), scaled to v_min..v_max, ``cycles`` periods of the lowest frequency.

Axes run ``together`` (the same waveform on every axis at once) or one after the other, the
others held at 0 V. Samples outside every block (ramps, settling) belong to no block.
No HTTP and no store here.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from drivers.bench import Bench
from drivers.interfaces import LimitError
from service.science.errors import FieldError

WAVEFORMS = ("sine", "step", "chirp", "multisine")
MAX_SAMPLES = 20_000_000  # 1000 s at 20 kHz: about 0.5 GB of float64 while running
MAX_CLOCK_DIVISOR = 2**32  # a 32-bit counter divides the DAQ timebase into the sample clock
MIN_SAMPLES_PER_CYCLE = 20  # fewer cannot resolve a hysteresis loop (as service.science.models requires)


class PlanError(FieldError):
    """A plan cannot run as given. ``field`` names the request field at fault."""


@dataclass(frozen=True)
class PlanBase:
    """Settings every plan shares (volts at the actuator, seconds, hertz)."""

    axes: tuple[str, ...] = ("y",)
    v_min: float = 0.0
    v_max: float = 120.0
    settle_s: float = 0.2
    sample_rate_hz: float = 20_000.0
    together: bool = True

    waveform = "base"

    def to_dict(self) -> dict:
        return {"waveform": self.waveform, **asdict(self)}


@dataclass(frozen=True)
class SinePlan(PlanBase):
    frequencies_hz: tuple[float, ...] = (1.0,)
    cycles: int = 5
    waveform = "sine"


@dataclass(frozen=True)
class StepPlan(PlanBase):
    levels_v: tuple[float, ...] = ()  # empty: one step to v_max
    hold_s: float = 2.0
    waveform = "step"


@dataclass(frozen=True)
class ChirpPlan(PlanBase):
    f_start_hz: float = 1.0
    f_stop_hz: float = 100.0
    duration_s: float = 10.0
    waveform = "chirp"


@dataclass(frozen=True)
class MultisinePlan(PlanBase):
    frequencies_hz: tuple[float, ...] = (1.0, 10.0, 50.0, 100.0)
    cycles: int = 5
    waveform = "multisine"


PLAN_TYPES: dict[str, type[PlanBase]] = {
    "sine": SinePlan,
    "step": StepPlan,
    "chirp": ChirpPlan,
    "multisine": MultisinePlan,
}


def plan_from_dict(values: dict) -> PlanBase:
    """Build the plan named by ``values['waveform']`` from the fields it knows (others ignored)."""
    waveform = values.get("waveform", "sine")
    if waveform not in PLAN_TYPES:
        raise PlanError("waveform", f"unknown waveform {waveform!r}; use one of {', '.join(WAVEFORMS)}")
    cls = PLAN_TYPES[waveform]
    known = set(cls.__dataclass_fields__)
    kwargs = {k: (tuple(v) if isinstance(v, list) else v) for k, v in values.items() if k in known and v is not None}
    return cls(**kwargs)


@dataclass
class PlannedSweep:
    """The waveform ready for ``Bench.run``: actuator volts per axis and the block table."""

    sample_rate_hz: float
    u_v: dict[str, np.ndarray]
    blocks: list[dict] = field(default_factory=list)

    @property
    def samples(self) -> int:
        return len(next(iter(self.u_v.values())))

    @property
    def duration_s(self) -> float:
        return self.samples / self.sample_rate_hz


def check_sample_rate(sample_rate_hz: float, timebase_hz: float = 100e6) -> float:
    """Return the rate if it divides the DAQ timebase exactly; PlanError naming the nearest ones."""
    if not (math.isfinite(sample_rate_hz) and sample_rate_hz > 0):
        raise PlanError("sample_rate_hz", "must be a positive number of hertz")
    divisor = timebase_hz / sample_rate_hz
    if not divisor <= MAX_CLOCK_DIVISOR:
        raise PlanError(
            "sample_rate_hz",
            f"{sample_rate_hz:g} Hz is below the slowest clock the "
            f"{timebase_hz / 1e6:g} MHz timebase can make ({timebase_hz / MAX_CLOCK_DIVISOR:.3g} Hz)",
        )
    if abs(divisor - round(divisor)) > 1e-9 * divisor or round(divisor) < 1:
        low, high = timebase_hz / math.ceil(divisor), timebase_hz / max(math.floor(divisor), 1)
        raise PlanError(
            "sample_rate_hz",
            f"{sample_rate_hz:g} Hz is not a divisor of the "
            f"{timebase_hz / 1e6:g} MHz timebase; nearest rates are {low:.6g} and {high:.6g} Hz",
        )
    return float(sample_rate_hz)


def build(plan: PlanBase, max_rate_v_per_s: float) -> PlannedSweep:
    """Turn a plan into waveforms and a block table. ``max_rate_v_per_s`` bounds the ramps."""
    fs = float(plan.sample_rate_hz)
    if plan.v_min >= plan.v_max and not isinstance(plan, StepPlan):
        raise PlanError("v_max", f"v_max ({plan.v_max:g} V) must exceed v_min ({plan.v_min:g} V)")
    estimate = _planned_seconds(plan) * fs * (1 if plan.together else len(plan.axes))
    if not estimate <= MAX_SAMPLES:  # refuse before allocating anything (also catches inf and NaN)
        raise PlanError(
            _length_field(plan),
            f"the plan lasts about {estimate / fs:.3g} s ({estimate:.3g} samples); "
            f"the limit is {MAX_SAMPLES} samples ({MAX_SAMPLES / fs:.0f} s at {fs:g} Hz)",
        )
    segment_of = {
        "sine": _sine_segments,
        "step": _step_segments,
        "chirp": _chirp_segments,
        "multisine": _multisine_segments,
    }[plan.waveform]
    pieces, blocks = segment_of(plan, fs, max_rate_v_per_s)
    one_axis = _assemble(pieces)
    axes = tuple(plan.axes)
    if plan.together or len(axes) == 1:
        u_v = {axis: one_axis for axis in axes}
        for block in blocks:
            block["axes"] = list(axes)
        all_blocks = blocks
    else:  # one axis after the other, the rest held at 0 V
        n = len(one_axis)
        u_v = {axis: np.zeros(n * len(axes)) for axis in axes}
        all_blocks = []
        for k, axis in enumerate(axes):
            u_v[axis][k * n : (k + 1) * n] = one_axis
            for block in blocks:
                all_blocks.append(
                    {**block, "start": block["start"] + k * n, "stop": block["stop"] + k * n, "axes": [axis]}
                )
    for index, block in enumerate(all_blocks):
        block["index"] = index
    planned = PlannedSweep(fs, u_v, all_blocks)
    if planned.samples > MAX_SAMPLES:
        raise PlanError(
            _length_field(plan),
            f"the plan lasts {planned.duration_s:.0f} s "
            f"({planned.samples} samples); the limit is {MAX_SAMPLES} samples",
        )
    return planned


def plan_for_bench(plan: PlanBase, bench: Bench) -> PlannedSweep:
    """Check a plan against the bench's axes, voltage range, current and slew limits, then build it.

    Every refusal is a PlanError naming the field at fault; nothing touches the hardware.
    """
    if not plan.axes:
        raise PlanError("axes", "give at least one axis")
    for axis in plan.axes:
        if axis not in bench.limits:
            raise PlanError("axes", f"unknown axis {axis!r}; this bench has {', '.join(bench.axes)}")
        lim = bench.limits[axis]
        if plan.v_min < lim.v_min_v:
            raise PlanError("v_min", f"{plan.v_min:g} V is below the actuator limit {lim.v_min_v:g} V")
        if plan.v_max > lim.v_max_v:
            raise PlanError("v_max", f"{plan.v_max:g} V is above the actuator limit {lim.v_max_v:g} V")
        for f_hz in _checked_frequencies(plan):
            try:
                bench.check_sine(axis, plan.v_max - plan.v_min, f_hz)
            except LimitError as exc:
                raise PlanError(_frequency_field(plan), f"axis {axis}: {exc}") from None
    caps = bench.parts.daq.capabilities
    check_sample_rate(plan.sample_rate_hz, caps.timebase_hz)
    if plan.sample_rate_hz > caps.max_sample_rate_hz:
        raise PlanError(
            "sample_rate_hz", f"{plan.sample_rate_hz:g} Hz is above the DAQ's {caps.max_sample_rate_hz:g} Hz"
        )
    fastest = max(_checked_frequencies(plan) + list(getattr(plan, "frequencies_hz", ())), default=0.0)
    if fastest and plan.sample_rate_hz < MIN_SAMPLES_PER_CYCLE * fastest:
        raise PlanError(
            "sample_rate_hz",
            f"{plan.sample_rate_hz:g} Hz gives fewer than {MIN_SAMPLES_PER_CYCLE} "
            f"samples per cycle at {fastest:g} Hz; a loop needs at least that many",
        )
    max_rate = min(bench.limits[a].max_rate_v_per_s for a in plan.axes)
    planned = build(plan, max_rate)
    try:
        bench.check_waveform(planned.u_v, planned.sample_rate_hz)
    except LimitError as exc:
        raise PlanError(_frequency_field(plan), str(exc)) from None
    return planned


def trim_blocks(blocks: list[dict], samples: int, sample_rate_hz: float) -> list[dict]:
    """The block table of a record cut short at ``samples``: later blocks dropped, the last one
    cut, its ``cycles`` reduced to the full cycles recorded and ``complete`` set to False."""
    out = []
    for block in blocks:
        if block["start"] >= samples:
            break
        block = dict(block)
        if block["stop"] > samples:
            block["stop"], block["complete"] = samples, False
            if block.get("frequency_hz") and block.get("cycles"):
                recorded_s = (samples - block["start"]) / sample_rate_hz
                block["cycles"] = int(math.floor(recorded_s * block["frequency_hz"] + 1e-9))
        out.append(block)
    return out


# ---------------------------------------------------------------------- segments
def _sine_segments(plan: SinePlan, fs: float, max_rate: float):
    if not plan.frequencies_hz or min(plan.frequencies_hz) <= 0:
        raise PlanError("frequencies_hz", "give at least one frequency, each above 0 Hz")
    if plan.cycles < 1:
        raise PlanError("cycles", "must be at least 1")
    pieces, blocks = _lead_in(plan, fs, max_rate)
    span = plan.v_max - plan.v_min
    for f_hz in plan.frequencies_hz:
        n = int(round(plan.cycles * fs / f_hz))
        t = np.arange(n) / fs
        blocks.append(_block(pieces, n, "sine", f_hz, plan.cycles))
        pieces.append(plan.v_min + span * (1 - np.cos(2 * np.pi * f_hz * t)) / 2)
        pieces.append(np.full(_n(plan.settle_s, fs), plan.v_min))
    pieces.append(_ramp(plan.v_min, 0.0, fs, max_rate))
    return pieces, blocks


def _step_segments(plan: StepPlan, fs: float, max_rate: float):
    levels = plan.levels_v or (plan.v_max,)
    for level in levels:
        if not plan.v_min <= level <= plan.v_max:
            raise PlanError("levels_v", f"level {level:g} V is outside v_min..v_max ({plan.v_min:g}–{plan.v_max:g} V)")
    if plan.hold_s <= 0:
        raise PlanError("hold_s", "must be positive")
    pieces, blocks = _lead_in(plan, fs, max_rate)
    hold = _n(plan.hold_s, fs)
    for level in levels:
        body = [
            _ramp(plan.v_min, level, fs, max_rate, fast=True),
            np.full(hold, float(level)),
            _ramp(level, plan.v_min, fs, max_rate, fast=True),
            np.full(hold, plan.v_min),
        ]
        n = sum(len(p) for p in body)
        blocks.append({**_block(pieces, n, "step", None, None), "level_v": float(level)})
        pieces.extend(body)
        pieces.append(np.full(_n(plan.settle_s, fs), plan.v_min))
    pieces.append(_ramp(plan.v_min, 0.0, fs, max_rate))
    return pieces, blocks


def _chirp_segments(plan: ChirpPlan, fs: float, max_rate: float):
    f0, f1 = plan.f_start_hz, plan.f_stop_hz
    if f0 <= 0 or f1 <= 0:
        raise PlanError("f_start_hz" if f0 <= 0 else "f_stop_hz", "must be a positive frequency")
    if plan.duration_s <= 0:
        raise PlanError("duration_s", "must be positive")
    # Round the duration so that the phase ends on a whole cycle, back at v_min.
    cycles = max(1, int(round((f0 + f1) / 2 * plan.duration_s)))
    duration = cycles / ((f0 + f1) / 2)
    n = int(round(duration * fs))
    t = np.arange(n) / fs
    phase = 2 * np.pi * (f0 * t + (f1 - f0) * t**2 / (2 * duration))
    pieces, blocks = _lead_in(plan, fs, max_rate)
    blocks.append({**_block(pieces, n, "chirp", None, cycles), "f_start_hz": f0, "f_stop_hz": f1})
    pieces.append(plan.v_min + (plan.v_max - plan.v_min) * (1 - np.cos(phase)) / 2)
    pieces.append(np.full(_n(plan.settle_s, fs), plan.v_min))
    pieces.append(_ramp(plan.v_min, 0.0, fs, max_rate))
    return pieces, blocks


def _multisine_segments(plan: MultisinePlan, fs: float, max_rate: float):
    freqs = sorted(plan.frequencies_hz)
    if not freqs or freqs[0] <= 0:
        raise PlanError("frequencies_hz", "give at least one positive frequency")
    base = freqs[0]
    harmonics = [f / base for f in freqs]
    if any(abs(h - round(h)) > 1e-6 for h in harmonics):
        raise PlanError(
            "frequencies_hz",
            f"multisine frequencies must be integer multiples of the "
            f"lowest ({base:g} Hz) so that the signal is periodic",
        )
    if plan.cycles < 1:
        raise PlanError("cycles", "must be at least 1")
    period_n = int(round(fs / base))
    t = np.arange(period_n) / fs
    k = np.arange(1, len(freqs) + 1)
    phases = -np.pi * k * (k - 1) / len(freqs)  # Schroeder phases: low crest factor
    one = np.sum([np.sin(2 * np.pi * f * t + p) for f, p in zip(freqs, phases)], axis=0)
    one = np.roll(one, -int(np.argmin(one)))  # start at the minimum: joins v_min smoothly
    one = (one - one.min()) / (one.max() - one.min())
    n = period_n * plan.cycles
    pieces, blocks = _lead_in(plan, fs, max_rate)
    blocks.append({**_block(pieces, n, "multisine", base, plan.cycles), "frequencies_hz": list(freqs)})
    pieces.append(plan.v_min + (plan.v_max - plan.v_min) * np.tile(one, plan.cycles))
    pieces.append(np.full(_n(plan.settle_s, fs), plan.v_min))
    pieces.append(_ramp(plan.v_min, 0.0, fs, max_rate))
    return pieces, blocks


# ---------------------------------------------------------------------- helpers
def _lead_in(plan: PlanBase, fs: float, max_rate: float):
    return [_ramp(0.0, plan.v_min, fs, max_rate), np.full(_n(plan.settle_s, fs), plan.v_min)], []


def _block(pieces: list[np.ndarray], n: int, kind: str, frequency_hz, cycles) -> dict:
    start = sum(len(p) for p in pieces)
    return {
        "index": 0,
        "start": start,
        "stop": start + n,
        "kind": kind,
        "cycles": cycles,
        "frequency_hz": None if frequency_hz is None else float(frequency_hz),
    }


def _ramp(v0: float, v1: float, fs: float, max_rate: float, fast: bool = False) -> np.ndarray:
    """Raised-cosine ramp from v0 to v1 (excluding v0) whose peak slope is a fraction of max_rate."""
    dv = v1 - v0
    if dv == 0:
        return np.zeros(0)
    peak = max_rate * (0.8 if fast else 0.25)
    n = max(2, int(math.ceil(math.pi * abs(dv) / (2 * peak) * fs)))
    s = np.arange(1, n + 1) / n
    return v0 + dv * (1 - np.cos(np.pi * s)) / 2


def _assemble(pieces: list[np.ndarray]) -> np.ndarray:
    return np.concatenate([np.asarray(p, dtype=float) for p in pieces]) if pieces else np.zeros(0)


def _n(seconds: float, fs: float) -> int:
    if seconds < 0:
        raise PlanError("settle_s", "must not be negative")
    return int(round(seconds * fs))


def _planned_seconds(plan: PlanBase) -> float:
    """Length of one axis's waveform, ramps aside (s); 0 where a field is invalid (checked later)."""
    settle = max(plan.settle_s, 0.0)
    if isinstance(plan, SinePlan):
        freqs = [f for f in plan.frequencies_hz if f > 0]
        return sum(max(plan.cycles, 0) / f + settle for f in freqs) + settle
    if isinstance(plan, MultisinePlan):
        low = min((f for f in plan.frequencies_hz if f > 0), default=0.0)
        return (max(plan.cycles, 0) / low if low else 0.0) + 2 * settle
    if isinstance(plan, ChirpPlan):  # the duration is rounded to whole cycles of the mean frequency, at least one
        mean_hz = (plan.f_start_hz + plan.f_stop_hz) / 2
        return max(max(plan.duration_s, 0.0) * 1.5, 1.0 / mean_hz if mean_hz > 0 else 0.0) + 2 * settle
    if isinstance(plan, StepPlan):
        return len(plan.levels_v or (plan.v_max,)) * (2 * max(plan.hold_s, 0.0) + settle) + settle
    return 0.0


def _checked_frequencies(plan: PlanBase) -> list[float]:
    if isinstance(plan, SinePlan):
        return [f for f in plan.frequencies_hz if f > 0]
    if isinstance(plan, ChirpPlan):
        return [max(plan.f_start_hz, plan.f_stop_hz)] if min(plan.f_start_hz, plan.f_stop_hz) > 0 else []
    return []


def _frequency_field(plan: PlanBase) -> str:
    return {"sine": "frequencies_hz", "multisine": "frequencies_hz", "chirp": "f_stop_hz"}.get(
        plan.waveform, "levels_v"
    )


def _length_field(plan: PlanBase) -> str:
    return {"sine": "cycles", "multisine": "cycles", "chirp": "duration_s"}.get(plan.waveform, "hold_s")
