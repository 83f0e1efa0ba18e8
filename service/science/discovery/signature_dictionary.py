"""The dictionary of physical signatures that what remains is read against
(service.science.discovery.remainder judges them): each a named set of regressor columns over a whole
record and the sentence its fitted coefficients make. Time, time × displacement (a gain that
changes), the drive level and its square, the rate and the rate times its magnitude, the error that
repeats cycle to cycle per block, lines not locked to the drive (the mains and the strongest line of
the residual, its frequency refined), the other axis, the temperature. Units: columns and residuals
in µm, time in s, drive in V; the sentences in nm, µs, Hz and %.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from service.science.data.holdout import axis_frequency_hz

#: lines tried at every diagnosis: the mains and their first harmonics (Hz)
MAINS_LINES_HZ = (50.0, 60.0, 100.0, 120.0, 150.0, 180.0)
#: the rate (Hz) the rows are pooled to (means of consecutive samples) before the signatures are fitted:
#: enough for the lines and the fifth harmonic of a 100 Hz block, and a tenth of the work at 20 kHz
POOL_RATE_HZ = 2500.0
#: harmonics of the block's frequency that "response per block" fits (the error that repeats cycle to cycle)
HARMONICS = 5


def pool(values: np.ndarray, q: int) -> np.ndarray:
    """Means of ``q`` consecutive rows (the last group may be shorter)."""
    if q <= 1:
        return values
    starts = np.arange(0, values.shape[0], q)
    counts = np.diff(np.append(starts, values.shape[0]))
    return np.add.reduceat(values, starts, axis=0) / (counts[:, None] if values.ndim == 2 else counts)


def pool_factor(records) -> int:
    """Samples pooled into one row (POOL_RATE_HZ at the slowest record's rate)."""
    return max(1, int(min(r.sample_rate_hz for r in records) // POOL_RATE_HZ))


@dataclass(frozen=True)
class Signature:
    """A physical signature: ``columns(rec, pred, ctx, rows)`` → (len(rows), k) regressors at the record's
    sample indices ``rows`` (None when the record cannot show it; k the same for every record of one
    diagnosis), built on those rows only; ``words(coef, ctx)`` →
    the sentence for fitted coefficients ``coef`` (µm per unit of each column). ``ctx``: duration_s,
    span_um and frequencies_hz (the distinct block frequencies of all the records)."""

    name: str
    columns: Callable[[object, np.ndarray, dict, np.ndarray], np.ndarray | None]
    words: Callable[[np.ndarray, dict], str]
    #: what the figure's x axis shows (the signature's own variable: the first column)
    x_label: str
    #: the last ``nested`` columns are a simpler signature's (drift under a changing gain, the rate under a
    #: rate limit): the signature counts only if its own columns explain significantly more than those
    nested: int = 0
    #: a shape repeated cycle to cycle: fitted on the training cycles and scored on the unseen rows
    #: (half a held-out cycle cannot teach the other half a waveform)
    from_training: bool = False


def _time_s(rec, rows: np.ndarray) -> np.ndarray:
    """The time (s) of the samples ``rows``."""
    return rows / rec.sample_rate_hz


def _drive_unit(rec, rows: np.ndarray) -> np.ndarray:
    """The drive at ``rows``, scaled to −1…1 over the record's span."""
    lo, hi = float(rec.u_v.min()), float(rec.u_v.max())
    return (rec.u_v[rows] - 0.5 * (lo + hi)) / max(0.5 * (hi - lo), 1e-12)


def _gain_words(coef, ctx) -> str:
    pct = 100.0 * coef[0] * ctx["duration_s"]
    return (
        f"the error grows in proportion to the displacement and to time: the gain "
        f"{'falls' if pct < 0 else 'rises'} {abs(pct):.2g} % over {ctx['duration_s']:.3g} s "
        "(depolarisation, self-heating, or a gauge drift)"
    )


def _drift_words(coef, ctx) -> str:
    nm = 1e3 * coef[0] * ctx["duration_s"]
    return (
        f"the error drifts with time, {1e3 * coef[0]:.3g} nm/s ({nm:+.3g} nm over {ctx['duration_s']:.3g} s), "
        "whatever the drive: a drift of the gauge, the mount or the amplifier's offset"
    )


def _square_words(coef, ctx) -> str:
    return (
        f"the error follows the square of the drive level ({1e3 * coef[0]:+.3g} nm at the ends of the span "
        "against the middle): a static nonlinearity of the stack or the gauge the model does not draw"
    )


#: where no rate limit can act on the records (the amplifier's rating is known and the drives stay well
#: under it), the rate words say so rather than name the amplifier
NOT_THE_AMPLIFIER = "not the amplifier: these drives stay well under its rated rate"


def _rate_words(coef, ctx) -> str:
    causes = (
        "a lag, a rate-dependent loop, or an amplifier that cannot follow the command (a slew-rate limit)"
        if ctx.get("amplifier_can_limit", True)
        else f"a lag or a rate-dependent loop ({NOT_THE_AMPLIFIER})"
    )
    return (
        "the error follows the drive's rate: it is largest where the drive moves fastest (the fastest block, "
        f"the steps) and changes sign with it: {causes}"
    )


def _slew_words(coef, ctx) -> str:
    causes = (
        "the amplifier cannot follow the command there (a slew-rate or current limit into the stack's capacitance)"
        if ctx.get("amplifier_can_limit", True)
        else f"a rate-dependent loop or a mode the model does not draw ({NOT_THE_AMPLIFIER})"
    )
    return f"the error grows with the square of the drive's rate and appears only where the rate is highest: {causes}"


def _block_words(coef, ctx) -> str:
    """Where the error that repeats cycle to cycle lives: its amplitude (nm) per block frequency (the
    columns: HARMONICS sine and cosine pairs of the block's phase, per frequency)."""
    freqs = ctx["frequencies_hz"]
    amp = 1e3 * np.sqrt(np.sum(coef.reshape(len(freqs), -1) ** 2, axis=1) / 2)
    parts = [f"{a:.3g} nm at {f:g} Hz" for a, f in zip(amp, freqs)]
    top, others = int(np.argmax(amp)), np.delete(amp, int(np.argmax(amp)))
    if top == len(freqs) - 1 and (others.size == 0 or amp[top] > 3 * others.max()):
        return (
            f"the error repeats cycle to cycle only in the fastest block ({'; '.join(parts)}), where the drive's "
            "rate is highest: "
            + (
                "the amplifier cannot follow there (a slew-rate or current limit into the stack's capacitance), "
                "or a mode near that frequency"
                if ctx.get("amplifier_can_limit", True)
                else f"a mode near that frequency or a rate-dependent loop ({NOT_THE_AMPLIFIER})"
            )
        )
    growth = np.polyfit(np.log(freqs), np.log(np.maximum(amp, 1e-9)), 1)[0] if len(freqs) >= 3 else 0.0
    if growth > 0.5:
        return (
            f"the error repeats cycle to cycle and grows with the drive's frequency, as f^{growth:.2g} "
            f"({'; '.join(parts)}): a rate-dependent loop, a lag or a mode"
        )
    return f"the error repeats cycle to cycle in every block ({'; '.join(parts)}): a loop shape the model does not draw"


def _other_axis_words(coef, ctx) -> str:
    return "the error follows the other axis's drive and motion: the axes are coupled (flexure or gauge cross-talk)"


def _temperature_words(coef, ctx) -> str:
    return (
        f"the error follows the temperature ({1e3 * coef[0]:+.3g} nm/K, and the gain "
        f"{100 * coef[1]:+.2g} %/K): thermal expansion and the stack's thermal gain"
    )


def _line_words(f_hz: float) -> Callable[[np.ndarray, dict], str]:
    def words(coef, ctx) -> str:
        amp = 1e3 * float(np.hypot(coef[0], coef[1]))
        mains = any(abs(f_hz - m) < 0.5 for m in MAINS_LINES_HZ)
        source = (
            "mains pickup on the gauge or the amplifier: shield or filter it; it is a disturbance, not a loop shape"
            if mains
            else "a disturbance from the surroundings (a machine, a fan) or a mode it excites; not a loop shape"
        )
        return f"a {f_hz:.4g} Hz line of {amp:.3g} nm whose phase runs on across blocks and rests, not locked to the drive: {source}"

    return words


def _line_columns(f_hz: float):
    def columns(rec, pred, ctx, rows):
        phase = 2 * np.pi * f_hz * _time_s(rec, rows)
        return np.column_stack([np.sin(phase), np.cos(phase)])

    return columns


def _block_columns(rec, pred, ctx, rows):
    """2·HARMONICS columns per distinct block frequency of the diagnosis, non-zero on the ``rows`` within
    its blocks: sines and cosines of the block's phase (the error that repeats cycle to cycle there)."""
    freqs = ctx["frequencies_hz"]
    if len(freqs) < 2:
        return None
    cols = np.zeros((rows.size, 2 * HARMONICS * len(freqs)))
    k = np.arange(1, HARMONICS + 1)
    for s in rec.splits:
        f = axis_frequency_hz(s.block, rec.axis)
        if f in freqs:
            a, b, at = s.train[0], s.held_out[1], 2 * HARMONICS * freqs.index(f)
            lo, hi = np.searchsorted(rows, (a, b))
            turn = np.exp(2j * np.pi * f * (rows[lo:hi] - a) / rec.sample_rate_hz)
            harmonic = turn[:, None] ** k[None, :]  # e^{ikφ}: one exponential, then powers
            cols[lo:hi, at : at + HARMONICS] = harmonic.imag
            cols[lo:hi, at + HARMONICS : at + 2 * HARMONICS] = harmonic.real
    return cols


def _other_columns(rec, pred, ctx, rows):
    if rec.u_other_v is None or np.ptp(rec.u_other_v) == 0:
        return None
    cols = [rec.u_other_v[rows]]
    if rec.x_other_um is not None and np.ptp(rec.x_other_um) > 0:
        cols.append(rec.x_other_um[rows])
    return np.column_stack(cols)


def _temperature_columns(rec, pred, ctx, rows):
    if rec.temp_c is None or np.ptp(rec.temp_c) == 0:
        return None
    dt = rec.temp_c[rows] - rec.temp_c[0]
    return np.column_stack([dt, dt * (pred[rows] - np.mean(pred))])


def _rate_unit(rec, rows: np.ndarray) -> np.ndarray:
    """The drive's rate at ``rows``, over the record's peak rate."""
    rate = rec.du_v_per_s
    return rate[rows] / max(float(np.max(np.abs(rate))), 1e-12)


def _gain_columns(rec, pred, ctx, rows):
    """time × displacement, then the nested drift (time) and static gain error (displacement): a gain that
    falls over the record leaves −g·(t − t̄)·x once the fit has taken its mean, so without the static
    column the time × displacement one took the sign of t̄·x (a fall of 1 % over 10.7 s read as a
    rise of 0.36 %)."""
    t, x = _time_s(rec, rows), pred[rows] - np.mean(pred)
    return np.column_stack([t * x, t, x])


def _square_columns(rec, pred, ctx, rows):
    level = _drive_unit(rec, rows)
    return np.column_stack([level**2, level])


def _rate_limit_columns(rec, pred, ctx, rows):
    rate = _rate_unit(rec, rows)
    return np.column_stack([rate * np.abs(rate), rate])


BUILT_IN = (
    Signature(
        "gain changing with time",
        _gain_columns,
        _gain_words,
        "time × displacement (s·µm)",
        nested=2,
    ),
    Signature("drift with time", lambda r, p, c, rows: _time_s(r, rows)[:, None], _drift_words, "time (s)"),
    Signature(
        "drive level squared",
        _square_columns,
        _square_words,
        "drive level (−1…1 of its span)",
        nested=1,
    ),
    Signature(
        "drive rate", lambda r, p, c, rows: _rate_unit(r, rows)[:, None], _rate_words, "drive rate (of its peak)"
    ),
    Signature(
        "rate limit",
        _rate_limit_columns,
        _slew_words,
        "rate × |rate| (of its peak²)",
        nested=1,
    ),
    Signature(
        "response per block", _block_columns, _block_words, "phase in the block's cycle (sin)", from_training=True
    ),
    Signature("other axis", _other_columns, _other_axis_words, "the other axis's drive (V)"),
    Signature("temperature", _temperature_columns, _temperature_words, "temperature change (K)"),
)


def _strongest_line_hz(records, residuals) -> float | None:
    """The strongest spectral line of the residuals (Hz) away from every block's drive harmonics
    (there a loop-shape error lies) and below 2 Hz (drift), refined between bins; None if none."""
    best, best_power = None, 0.0
    q = pool_factor(records)
    for rec, full in zip(records, residuals):
        res, rate = pool(full, q), rec.sample_rate_hz / q
        n = res.size
        if n < 64:
            continue
        spectrum = np.abs(np.fft.rfft((res - res.mean()) * np.hanning(n))) ** 2
        freqs = np.fft.rfftfreq(n, 1.0 / rate)
        keep = (freqs > 2.0) & (freqs < rate / 2.5)
        resolution = rate / n
        for s in rec.splits:
            f0 = axis_frequency_hz(s.block, rec.axis)
            if f0:
                harmonic = np.round(freqs / f0)
                keep &= ~((harmonic >= 1) & (np.abs(freqs - harmonic * f0) <= max(3 * resolution, 0.01 * f0)))
        if not keep.any():
            continue
        k = int(np.argmax(np.where(keep, spectrum, 0.0)))
        if spectrum[k] > best_power:
            best, best_power = (
                _refined_line_hz(res, rate, float(freqs[k]), resolution),
                float(spectrum[k]),
            )
    return best


def _refined_line_hz(res: np.ndarray, sample_rate_hz: float, coarse_hz: float, resolution_hz: float) -> float:
    """The frequency (Hz) within a bin and a half of ``coarse_hz`` where the residual's power is largest,
    by golden-section search (the power is unimodal there): over a long record a line's phase runs off
    if its frequency is a bin wrong."""
    t = np.arange(res.size) / sample_rate_hz
    r = res - res.mean()

    def power(f: float) -> float:
        return abs(np.dot(r, np.exp(-2j * np.pi * f * t)))

    lo, hi = coarse_hz - 1.5 * resolution_hz, coarse_hz + 1.5 * resolution_hz
    ratio = (np.sqrt(5) - 1) / 2
    a, b = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    pa, pb = power(a), power(b)
    while hi - lo > 1e-3 * resolution_hz:
        if pa > pb:
            hi, b, pb = b, a, pa
            a = hi - ratio * (hi - lo)
            pa = power(a)
        else:
            lo, a, pa = a, b, pb
            b = lo + ratio * (hi - lo)
            pb = power(b)
    return float(0.5 * (lo + hi))


def line_signatures(records, residuals) -> list[Signature]:
    lines = list(MAINS_LINES_HZ)
    top = _strongest_line_hz(records, residuals)
    if top is not None and all(abs(top - m) > 0.5 for m in lines):
        lines.append(round(top, 3))
    fs = min(r.sample_rate_hz for r in records)
    return [
        Signature(f"line at {f:g} Hz", _line_columns(f), _line_words(f), f"phase of the {f:g} Hz line (°)")
        for f in lines
        if f < fs / 2.5
    ]
