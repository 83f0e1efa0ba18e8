"""What the data must contain before an effect can be tested: the helpers the effects' identifiability
rules (``Effect.untestable``) share. Pure numpy: records in, numbers or a reason in words out."""

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


def two_rates(name: str, records) -> str | None:
    """The rate effects' rule: at least two drive rates a factor MIN_RATE_RATIO apart (None: met)."""
    rates = drive_rates_hz(records)
    if len(rates) >= 2 and rates[-1] >= MIN_RATE_RATIO * rates[0]:
        return None
    seen = ", ".join(f"{f:.3g} Hz" for f in rates) or "no periodic block"
    return (
        f"{name} needs at least two drive rates a factor {MIN_RATE_RATIO:g} apart (this data: "
        f"{seen}): at one rate it is one fixed loop shape, which the hysteresis base absorbs"
    )


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


def temperature_span(records) -> str | None:
    """The temperature effect's rule: a ``temp_c`` column spanning MIN_TEMPERATURE_SPAN_K (None: met)."""
    temps = [r.temp_c for r in records if getattr(r, "temp_c", None) is not None]
    span = float(np.ptp(np.concatenate(temps))) if temps else 0.0
    if span >= MIN_TEMPERATURE_SPAN_K:
        return None
    seen = f"it spans {span:.2f} K" if temps else "the record has no temp_c column"
    return (
        f"a temperature effect needs a temp_c column that varies by at least "
        f"{MIN_TEMPERATURE_SPAN_K:g} K ({seen}): record the stack's temperature over a run "
        "long enough for it to change"
    )


def independent_other_axis(records) -> str | None:
    """Cross-coupling's rule: the other axis driven, independently of this one (None: met)."""
    share = other_axis_independence(records)
    if share is None:
        return "the record has no drive of the other axis, so its influence cannot be seen"
    if not any(r.u_other_v is not None and np.ptp(r.u_other_v) > 0 for r in records):
        return "the other axis was not driven (its drive is constant), so its influence cannot be seen"
    if share < INDEPENDENT_SHARE:
        return (
            f"the other axis was driven with this axis's waveform (only {100 * share:.1f} % of its "
            "drive is independent of this axis's): collinear drives make coupling "
            "indistinguishable from more hysteresis; drive each axis alone"
        )
    return None


def growth_words(sig: dict) -> str:
    """How the residual grows with the drive frequency, in words (``sig``: the diagnosis's signatures)."""
    g = sig.get("rms_growth_exponent")
    if g is None:
        return "frequency growth unknown"
    return f"the residual {'grows' if g >= 0 else 'falls'} with frequency as f^{g:.2f}"
