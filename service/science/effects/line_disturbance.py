"""A disturbance at a line frequency: mains pickup on the gauge or the amplifier (50/60 Hz and their
harmonics), or any strong line not locked to the drive (a machine, a fan), added to what the gauge reads.

Columns: sin and cos of 2π·f·t at each line (t in s from the record's start), weights in µm. The lines are
learned before any fit (``setup``) where the stage does nothing the model must draw: at rest, the drive
held at the level the record starts from. The mains and their harmonics up to the fifth are fitted there
on one half of every rest stretch and scored on the other (a line must lower the held-out mean square
by more than LINE_Z noise standard errors); without rests no line is learned and the effect is
not testable. A line's phase is the mains', not the drive's, so a feedforward cannot cancel it.

The diagnosis reads the record's rests first (service.science.discovery.rests, with a finer search of
its own) and takes the lines it finds out of the record before the model is judged, so that no loop
shape is claimed for them; this effect is then the named cause, with the rests' held-out test as its
evidence. It draws a point-symmetric nothing of the loop: never a loop-shape effect.
"""

from __future__ import annotations

import numpy as np

from service.science.data.units import fmt_nm
from service.science.effects.base import Effect, RecordContext
from service.science.fitting.lsq import Block

#: the mains and harmonics looked at (Hz)
MAINS_HZ = tuple(sorted({m * k for m in (50.0, 60.0) for k in range(1, 6)}))
#: rows within this share of the drive's span of the level the record starts from, and still, are at rest
REST_SHARE = 0.01
#: a rest stretch is read after this long (s) and only if this long (s) is left
SETTLE_S, MIN_STRETCH_S = 0.05, 0.1
#: a line's held-out drop in mean square must exceed this many standard errors (one-sided, ten lines)
LINE_Z = 3.5
#: the line the columns carry when none was learned (a model fitted without rests)
DEFAULT_HZ = (50.0,)


def rest_stretches(u_v: np.ndarray, fs_hz: float) -> list[tuple[int, int]]:
    """(start, stop) rows where the drive ``u_v`` rests at the level it starts from, settled."""
    span = max(float(np.ptp(u_v)), 1e-12)
    rest = np.abs(u_v - u_v[0]) <= REST_SHARE * span
    edges = np.flatnonzero(np.diff(np.concatenate([[0], rest.astype(np.int8), [0]])))
    out = []
    for a, b in zip(edges[::2], edges[1::2]):
        a += int(SETTLE_S * fs_hz) if a > 0 else 0
        if b - a >= MIN_STRETCH_S * fs_hz:
            out.append((int(a), int(b)))
    return out


def _sin_cos(t_s: np.ndarray, f_hz: float) -> np.ndarray:
    return np.column_stack([np.sin(2 * np.pi * f_hz * t_s), np.cos(2 * np.pi * f_hz * t_s)])


def held_out_z(records, f_hz: float) -> float:
    """The line at ``f_hz``'s held-out drop in mean square over the rests, in standard errors: fitted
    (with each stretch's mean and slope) on one half of every stretch and scored on the other, and back."""
    drops = []
    for rec in records:
        for a, b in rest_stretches(rec.u_v, rec.sample_rate_hz):
            t, x = np.arange(a, b) / rec.sample_rate_hz, rec.x_um[a:b]
            half = (b - a) // 2
            trend = np.column_stack([np.ones(b - a), t - t.mean()])
            x = x - trend @ np.linalg.lstsq(trend, x, rcond=None)[0]
            cols = _sin_cos(t, f_hz)
            for fit, score in ((slice(0, half), slice(half, None)), (slice(half, None), slice(0, half))):
                coef = np.linalg.lstsq(cols[fit], x[fit], rcond=None)[0]
                drops.append(x[score] ** 2 - (x[score] - cols[score] @ coef) ** 2)
    if not drops:
        return 0.0
    d = np.concatenate(drops)
    return float(d.mean() / (d.std() / np.sqrt(d.size))) if d.std() > 0 else 0.0


class LineDisturbance(Effect):
    name = "line_disturbance"
    signature = (
        "a line at a fixed frequency (mains 50/60 Hz or a harmonic, or any strong line) that is on the gauge "
        "at rest too and keeps its own phase, not the drive's: a disturbance, not the stack"
    )
    units = {"line_um": "µm", "line_hz": "Hz", "line_amplitude_nm": "nm"}
    rule = (
        "rests in the record (the drive held at the level it starts from for ≥ 0.1 s) where a line shows: at "
        "rest the stage draws nothing, so a line there is a disturbance"
    )
    sweep = {"waveform": "sine", "frequencies_hz": [1.0, 10.0, 50.0, 100.0], "cycles": 5, "settle_s": 1.0}
    inverse = "none"
    no_inverse = (
        "a line keeps the mains' phase, not the plan's: no drive planned ahead can cancel it; shield or filter "
        "the gauge, or subtract it from the reading"
    )
    emulator_bench = "line_disturbance"
    seen_at_rest = True

    def setup(self, records) -> dict:
        """``line_hz``: the mains lines (and harmonics) whose held-out z at rest exceeds LINE_Z."""
        top = min(r.sample_rate_hz for r in records) / 2.5
        return {"line_hz": [f for f in MAINS_HZ if f < top and held_out_z(records, f) > LINE_Z]}

    def blocks(self, ctx: RecordContext) -> list[Block]:
        lines = ctx.learned.get(self.name, {}).get("line_hz") or DEFAULT_HZ
        return [Block.make("line_um", np.column_stack([_sin_cos(ctx.t_s, f) for f in lines]))]

    def untestable(self, records) -> str | None:
        if not any(rest_stretches(r.u_v, r.sample_rate_hz) for r in records):
            return (
                "a line is told from the stack at rest, and the record has no rest (the drive held at its "
                "starting level for ≥ 0.1 s): record one before and between the blocks"
            )
        if not self.setup(records)["line_hz"]:
            return "no line of the mains or its harmonics shows at rest above the gauge's noise"
        return None

    def parameters(self, theta, values, scales, sign):
        """The largest line's amplitude (nm) and frequency (Hz) among those fitted."""
        coef, lines = values.get("line_um"), scales.get("learned", {}).get(self.name, {}).get("line_hz")
        if coef is None or not lines:
            return {}
        amps = np.hypot(np.asarray(coef)[0::2], np.asarray(coef)[1::2])
        k = int(np.argmax(amps))
        return {"line_hz": float(lines[k]), "line_amplitude_nm": float(amps[k]) * 1e3}

    def evidence(self, sig, floor):
        lines = floor.get("disturbance_lines") or []
        if not lines:
            return self.signature
        named = ", ".join(f"{li['frequency_hz']:.4g} Hz ({fmt_nm(li['amplitude_um'])})" for li in lines)
        return f"lines on the gauge at rest, where the stage draws nothing: {named}: line_disturbance"
