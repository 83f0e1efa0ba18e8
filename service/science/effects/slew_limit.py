"""The amplifier's slew-rate or current limit: the stack sees a rate-limited drive.

A piezo amplifier charges the stack (a capacitance C, F) with at most its rated current I (A), so the
stack's voltage moves at most I/C volts a second (0.2 A into 1.8 µF: 111 kV/s), or at its own slew
rating if that is lower. Where the planned drive moves faster (the 100 Hz block of a 120 V sweep needs
π·100·120 = 37.7 kV/s at its steepest), the stack lags behind the plan and catches up where the plan
slows down; below the limit nothing happens.

Stage ``drive``: everything else of the model (the hysteresis base, every effect) sees the limited drive
u_s, with u_s[k] = u_s[k−1] + clip(u[k] − u_s[k−1], ±S/fs), u_s[0] = u[0]. S (V/s) is found by a 1-D
search from the records' fastest drive rate down to a tenth of it (the identity: S at or above the fastest
rate). No inverse: a feedforward cannot ask the amplifier for more current than it has; a plan must keep
its rate under S (slow the trajectory, or a larger amplifier).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from drivers.jit import njit
from service.science.data.units import plain
from service.science.effects.base import Effect
from service.science.effects.rules import growth_words

#: the grid: from 5 % above the records' fastest drive rate (no limit) down by this factor per step, to a
#: tenth of it (the error grows fast below the true limit: 10 nm at the limit, 260 nm at 15 % under it)
GRID_STEP, GRID_SPAN = 1.1, 10.0
#: evaluations of the bounded search between grid values
REFINE_EVALUATIONS = 10
#: where the bench that recorded the data is known, a limit can bite only if the drive's fastest rate
#: comes within this factor of the amplifier's rated I/C: a stack's capacitance at large signal exceeds
#: its small-signal rating (the emulated slew bench's stacks by 1.75×), so the rating alone is not the bound
RATED_MARGIN = 2.0


@njit(cache=True, nogil=True)
def _rate_limited(u, step):
    out = np.empty(u.size)
    if u.size == 0:
        return out
    y = u[0]
    out[0] = y
    for k in range(1, u.size):
        d = u[k] - y
        if d > step:
            d = step
        elif d < -step:
            d = -step
        y += d
        out[k] = y
    return out


def rate_limited(u_v: np.ndarray, fs_hz: float, slew_v_per_s: float) -> np.ndarray:
    """``u_v`` (V) as a stage whose voltage moves at most ``slew_v_per_s`` (V/s) follows it at ``fs_hz``."""
    return _rate_limited(np.ascontiguousarray(u_v, dtype=float), float(slew_v_per_s) / fs_hz)


def amplifier_slew_v_per_s(current_a: float, capacitance_f: float, slew_v_per_s: float | None = None) -> float:
    """The rate (V/s) an amplifier of rated ``current_a`` (A) can move a stack of ``capacitance_f`` (F):
    I/C, or its own slew rating where that is lower."""
    limit = current_a / capacitance_f
    return min(limit, slew_v_per_s) if slew_v_per_s else limit


class SlewLimit(Effect):
    name = "slew_limit"
    stage = "drive"
    limits_rate = True
    point_symmetric = True  # a rate limit of a point-symmetric drive is point-symmetric
    signature = (
        "the error appears only where the drive's rate is highest (the fastest block's steepest parts) and "
        "lags there by more than any delay: the amplifier cannot deliver the current to follow the drive"
    )
    #: the stored parameter (V/s) and the one the user reads (kV/s, the bench page's and the evidence's unit:
    #: ``parameters`` reports it alone)
    units = {"slew_v_per_s": "V/s", "slew_kv_per_s": "kV/s"}
    rule = (
        "a drive whose fastest rate exceeds the limit, beside blocks that stay under it: the error appears above "
        "a rate, not in proportion to the frequency; on a bench whose amplifier rating is known, the fastest rate "
        "must reach half its rated I/C"
    )
    sweep = {"waveform": "sine", "frequencies_hz": [10.0, 50.0, 100.0, 150.0], "cycles": 10}
    inverse = "none"
    no_inverse = (
        "a rate limit cannot be undone by asking for more: the amplifier has no more current; keep the plan's "
        "rate under the fitted limit (slower, or a smaller stroke) or use a larger amplifier"
    )
    identity = {"slew_v_per_s": 1e12}
    emulator_bench = "slew_limit"
    separated_from = {
        "delay": (
            "a sweep at one frequency with rising amplitude: a delay is the same time at every amplitude, a "
            "rate limit bites only above the rate it allows",
            {"waveform": "sine", "frequencies_hz": [100.0], "cycles": 10},
        ),
    }

    def grid(self, fs_hz, min_period_s, max_frequency_hz):
        """Drive stages: ``max_frequency_hz`` is the records' fastest drive rate (V/s) here."""
        top = 1.05 * float(max_frequency_hz)
        steps = int(np.ceil(np.log(GRID_SPAN) / np.log(GRID_STEP)))
        return [{"slew_v_per_s": top / GRID_STEP**k} for k in range(steps + 1)]

    def drive(self, u_v, fs_hz, theta):
        return rate_limited(u_v, fs_hz, theta["slew_v_per_s"])

    def clamp(self, theta, fs_hz):
        return {"slew_v_per_s": max(float(theta["slew_v_per_s"]), 1.0)}

    def refine(self, theta, cost, fine: bool = False, bracket=None):
        """The limit between the grid values beside the best one, on a log scale."""
        s0 = theta["slew_v_per_s"]
        lo, hi = (bracket[0]["slew_v_per_s"], bracket[1]["slew_v_per_s"]) if bracket else (0.8 * s0, 1.25 * s0)
        lo, hi = np.log(min(lo, hi, s0)), np.log(max(lo, hi, s0))
        res = minimize_scalar(
            lambda x: cost({"slew_v_per_s": float(np.exp(x))}),
            bounds=(lo, hi),
            method="bounded",
            options={"maxiter": REFINE_EVALUATIONS},
        )
        return {"slew_v_per_s": float(np.exp(res.x))} if res.fun <= cost(theta) else theta

    def describe(self, theta, values):
        s = (theta or {}).get("slew_v_per_s")
        return "" if s is None else f"the stack's voltage moves at most {plain(s / 1e3)} kV/s"

    def parameters(self, theta, values, scales, sign):
        s = (theta or {}).get("slew_v_per_s")
        return {} if s is None else {"slew_kv_per_s": float(s) / 1e3}

    def untestable(self, records):
        """None when a rate limit could act on ``records``: their drive moves and, where the amplifier that
        recorded them is known (``Record.rated_rate_v_per_s``), comes within RATED_MARGIN of its rating."""
        fastest = [float(np.max(np.abs(np.diff(r.u_v)))) * r.sample_rate_hz for r in records]
        if not fastest or max(fastest) <= 0:
            return "the drive does not move: no rate to limit"
        rated = [r.rated_rate_v_per_s for r in records]
        if any(v is None for v in rated) or any(f * RATED_MARGIN >= v for f, v in zip(fastest, rated)):
            return None  # an import's amplifier is unknown; a drive near the rating can be held back
        return (
            f"the drive's fastest rate, {max(fastest) / 1e3:.3g} kV/s, stays under 1/{RATED_MARGIN:g} of the rate the "
            f"amplifier that recorded it is rated to move the stack ({min(rated) / 1e3:.3g} kV/s: its current over the "
            "stack's capacitance, or its slew rating), a margin wider than a stack's large-signal capacitance "
            "exceeds its rating: no rate limit can act on these records"
        )

    def evidence(self, sig, floor):
        steep = f" ({growth_words(sig)})" if sig.get("rms_growth_exponent") is not None else ""
        return (
            "the error is largest where the drive is steepest" + steep + ": the amplifier's current limit (I/C) "
            "or slew rate holds the stack back: slew_limit"
        )
