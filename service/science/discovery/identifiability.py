"""What the data must contain before an effect can be tested at all.

An effect the experiment cannot tell apart from the hysteresis base, or from another effect, is
*not testable* on that data: it is reported with the reason and a ready-to-POST ``/api/sweeps``
body that would test it, and it is never claimed. The rules, in words:

- ``cross_coupling``: the other axis must be driven **independently** of this one. With both axes
  driven by the same waveform (collinear drives, e.g. Z at 80 % of Y), the other axis's drive is
  just this axis's drive rescaled, and "coupling" is indistinguishable from more hysteresis.
- ``rate_dependence``, ``delay``, ``dynamics``: at least two drive rates a factor ≥ 2 apart. At one
  rate a delay, a rate-dependent loop and a resonance are all one fixed loop shape.
- ``creep`` and ``drift``: testable on any record long enough to see a slow change; telling them
  apart needs a hold after a step (creep relaxes and reverses with the step, drift does not),
  which the ambiguity report asks for.
- ``asymmetry``: a drive that spans a range (any loop).
- ``temperature``: a ``temp_c`` column that varies by at least MIN_TEMPERATURE_SPAN_K.
Pure numpy: no store, no HTTP.
"""

from __future__ import annotations

import numpy as np

from service.science.data.holdout import axis_frequency_hz

#: the characterisation that tests every rate effect (the paper's four frequencies)
RATE_SWEEP = {"waveform": "sine", "frequencies_hz": [1.0, 10.0, 50.0, 100.0], "cycles": 5}
#: two rates must differ by at least this factor to separate a rate effect from the loop shape
MIN_RATE_RATIO = 2.0
#: the other axis's drive must keep this share of its RMS after the best linear fit on this axis's
#: drive (and an offset) to count as independent of it
INDEPENDENT_SHARE = 0.05

RATE_EFFECTS = ("rate_dependence", "delay", "dynamics")
#: a temperature effect needs the recorded temperature to span at least this much (K)
MIN_TEMPERATURE_SPAN_K = 0.5


def drive_rates_hz(records) -> list[float]:
    """The distinct periodic drive rates (Hz) of the blocks that drive this axis."""
    rates = []
    for r in records:
        for s in r.splits_of(own_axis_only=True):
            own = axis_frequency_hz(s.block, r.axis) if "frequencies_hz" in s.block else None
            period = r.period_samples(s)
            if own or period:
                rates.append(own or r.sample_rate_hz / period)
    distinct: list[float] = []
    for f in sorted(rates):
        if not distinct or f > distinct[-1] * 1.05:
            distinct.append(f)
    return distinct


def other_axis_independence(records) -> float | None:
    """The share (0..1) of the other axis's drive RMS that this axis's drive cannot explain linearly,
    over every record that has both; None when no record has the other axis's drive."""
    num = den = 0.0
    seen = False
    for r in records:
        if r.u_other_v is None:
            continue
        seen = True
        a = np.column_stack([r.u_v, np.ones(r.n_samples)])
        coef, *_ = np.linalg.lstsq(a, r.u_other_v, rcond=None)
        rest = r.u_other_v - a @ coef
        centred = r.u_other_v - r.u_other_v.mean()
        num += float(np.sum(rest**2))
        den += float(np.sum(centred**2))
    if not seen:
        return None
    return float(np.sqrt(num / den)) if den > 0 else 0.0


def experiment_body(records, axes: list[str], **body) -> dict:
    """A ready-to-POST /api/sweeps body on ``axes``; a sine sweep spans the data's own drive range
    (``v_min``/``v_max``, V, rounded out to 0.1 V), so that an experiment asked for data of another
    stage or range is that range — and a bench that cannot drive it refuses it, naming the field."""
    out = {"axes": axes, **body}
    drives = [np.asarray(r.u_v, dtype=float) for r in records if getattr(r, "u_v", None) is not None and r.u_v.size]
    if body.get("waveform") == "sine" and drives:
        lo, hi = min(float(u.min()) for u in drives), max(float(u.max()) for u in drives)
        if hi > lo:
            out.update(v_min=float(np.floor(lo * 10.0) / 10.0), v_max=float(np.ceil(hi * 10.0) / 10.0))
    return out


def _axes(records) -> list[str]:
    return sorted({r.axis for r in records if r.axis}) or ["y"]


def _other(axis: str) -> str:
    return {"y": "z", "z": "y"}.get(axis, "z")


def not_testable(effect: str, records) -> dict | None:
    """None when ``records`` can test ``effect``; else ``{"effect", "reason", "experiment"}`` with
    the ``/api/sweeps`` body that would make it testable."""
    axes = _axes(records)
    if effect == "cross_coupling":
        share = other_axis_independence(records)
        both_axes = experiment_body(records, sorted(set(axes) | {_other(axes[0])}), **RATE_SWEEP, together=False)
        if share is None:
            return {
                "effect": effect,
                "reason": "the record has no drive of the other axis, so its influence cannot be seen",
                "experiment": both_axes,
            }
        if not any(r.u_other_v is not None and np.ptp(r.u_other_v) > 0 for r in records):
            return {
                "effect": effect,
                "reason": "the other axis was not driven (its drive is constant), so its influence cannot be seen",
                "experiment": both_axes,
            }
        if share < INDEPENDENT_SHARE:
            return {
                "effect": effect,
                "reason": f"the other axis was driven with this axis's waveform (only {100 * share:.1f} % of its "
                "drive is independent of this axis's): collinear drives make coupling "
                "indistinguishable from more hysteresis; drive each axis alone",
                "experiment": both_axes,
            }
        return None
    if effect == "temperature":
        temps = [r.temp_c for r in records if getattr(r, "temp_c", None) is not None]
        span = float(np.ptp(np.concatenate(temps))) if temps else 0.0
        if span < MIN_TEMPERATURE_SPAN_K:
            seen = f"it spans {span:.2f} K" if temps else "the record has no temp_c column"
            return {
                "effect": effect,
                "reason": f"a temperature effect needs a temp_c column that varies by at least "
                f"{MIN_TEMPERATURE_SPAN_K:g} K ({seen}): record the stack's temperature over a run "
                "long enough for it to change",
                "experiment": experiment_body(records, axes, waveform="sine", frequencies_hz=[1.0], cycles=60),
            }
        return None
    if effect in RATE_EFFECTS:
        rates = drive_rates_hz(records)
        if len(rates) < 2 or rates[-1] < MIN_RATE_RATIO * rates[0]:
            seen = ", ".join(f"{f:.3g} Hz" for f in rates) or "no periodic block"
            return {
                "effect": effect,
                "reason": f"{effect} needs at least two drive rates a factor {MIN_RATE_RATIO:g} apart (this data: "
                f"{seen}): at one rate it is one fixed loop shape, which the hysteresis base absorbs",
                "experiment": experiment_body(records, axes, **RATE_SWEEP),
            }
    return None
