"""What remains, described: the residual a model leaves, read against a dictionary of physical
signatures, so that an effect the library cannot name is still described in a physicist's words.

A signature is a named set of regressor columns over the whole record: time, time × displacement (a
gain that changes), the drive level and its square, the rate and the rate times its magnitude (an
amplifier that cannot follow), a gain per block (the response against the block's frequency), lines
not locked to the drive (mains 50/60 Hz and harmonics, and the strongest line in the residual), the
other axis's drive and motion, and the temperature where it was recorded.

The same held-out discipline as the claims: a signature is judged only on rows the model never
fitted — the held-out cycles, and outside the blocks the rests and holds — by two-fold
cross-validation (every stretch cut in halves: fitted on the first halves, scored on the second, and back), against the gauge
noise with a one-sided threshold corrected for the number of signatures tried (Bonferroni), so that a
signature is not read into noise. Units: residuals in µm in, nm in the texts; time in s; drive in V.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from service.science.data.holdout import axis_frequency_hz

#: family-wise false-description rate over the signatures tried on one residual
FAMILY_ALPHA = 0.01
#: contiguous chunks the unseen rows are cut into for the gain's t-test (fewer on short records)
CHUNKS = 40
#: lines tried at every diagnosis: the mains and their first harmonics (Hz)
MAINS_LINES_HZ = (50.0, 60.0, 100.0, 120.0, 150.0, 180.0)
#: signatures reported, best first
TOP = 3
#: points of a signature's figure (the unseen rows, decimated evenly)
FIGURE_POINTS = 400
#: the rate (Hz) the rows are pooled to (means of consecutive samples) before the signatures are fitted:
#: enough for the lines and the fifth harmonic of a 100 Hz block, and a tenth of the work at 20 kHz
POOL_RATE_HZ = 2500.0
#: a rest or a hold: the drive's rate below this share of its 95th-percentile rate
STILL_RATE_SHARE = 0.01
#: harmonics of the block's frequency that "response per block" fits (the error that repeats cycle to cycle)
HARMONICS = 5
#: a signature is reported when it explains at least this share of what remains above the gauge noise
#: on the unseen rows: a reporting choice (below it the sentence would describe a sliver), not the test
MIN_SHARE = 0.05


@dataclass(frozen=True)
class Signature:
    """A physical signature: ``columns(rec, pred, ctx)`` → (n, k) regressors over the record (None when
    the record cannot show it; k the same for every record of one diagnosis); ``words(coef, ctx)`` →
    the sentence for fitted coefficients ``coef`` (µm per unit of each column). ``ctx``: duration_s,
    span_um and frequencies_hz (the distinct block frequencies of all the records)."""

    name: str
    columns: Callable[[object, np.ndarray, dict], np.ndarray | None]
    words: Callable[[np.ndarray, dict], str]
    #: what the figure's x axis shows (the signature's own variable: the first column)
    x_label: str
    #: the last ``nested`` columns are a simpler signature's (drift under a changing gain, the rate under a
    #: rate limit): the signature counts only if its own columns explain significantly more than those
    nested: int = 0
    #: a shape repeated cycle to cycle: fitted on the training cycles and scored on the unseen rows
    #: (half a held-out cycle cannot teach the other half a waveform)
    from_training: bool = False


def _time_s(rec) -> np.ndarray:
    return np.arange(rec.u_v.size) / rec.sample_rate_hz


def _drive_unit(rec) -> np.ndarray:
    """The drive scaled to −1…1 over its span."""
    lo, hi = float(rec.u_v.min()), float(rec.u_v.max())
    return (rec.u_v - 0.5 * (lo + hi)) / max(0.5 * (hi - lo), 1e-12)


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


def _rate_words(coef, ctx) -> str:
    return (
        "the error follows the drive's rate: it is largest where the drive moves fastest (the fastest block, "
        "the steps) and changes sign with it: a lag, a rate-dependent loop, or an amplifier that cannot follow "
        "the command (a slew-rate limit)"
    )


def _slew_words(coef, ctx) -> str:
    return (
        "the error grows with the square of the drive's rate and appears only where the rate is highest: the "
        "amplifier cannot follow the command there (a slew-rate or current limit into the stack's capacitance)"
    )


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
            "rate is highest: the amplifier cannot follow there (a slew-rate or current limit into the stack's "
            "capacitance), or a mode near that frequency"
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
    def columns(rec, pred, ctx):
        phase = 2 * np.pi * f_hz * _time_s(rec)
        return np.column_stack([np.sin(phase), np.cos(phase)])

    return columns


def _block_columns(rec, pred, ctx):
    """2·HARMONICS columns per distinct block frequency of the diagnosis, non-zero within its blocks:
    sines and cosines of the block's phase (the error that repeats cycle to cycle there)."""
    freqs = ctx["frequencies_hz"]
    if len(freqs) < 2:
        return None
    cols = np.zeros((rec.u_v.size, 2 * HARMONICS * len(freqs)))
    k = np.arange(1, HARMONICS + 1)
    for s in rec.splits:
        f = axis_frequency_hz(s.block, rec.axis)
        if f in freqs:
            a, b, at = s.train[0], s.held_out[1], 2 * HARMONICS * freqs.index(f)
            turn = np.exp(2j * np.pi * f * np.arange(b - a) / rec.sample_rate_hz)
            harmonic = turn[:, None] ** k[None, :]  # e^{ikφ}: one exponential, then powers
            cols[a:b, at : at + HARMONICS] = harmonic.imag
            cols[a:b, at + HARMONICS : at + 2 * HARMONICS] = harmonic.real
    return cols


def _other_columns(rec, pred, ctx):
    if rec.u_other_v is None or np.ptp(rec.u_other_v) == 0:
        return None
    cols = [rec.u_other_v]
    if rec.x_other_um is not None and np.ptp(rec.x_other_um) > 0:
        cols.append(rec.x_other_um)
    return np.column_stack(cols)


def _temperature_columns(rec, pred, ctx):
    if rec.temp_c is None or np.ptp(rec.temp_c) == 0:
        return None
    dt = rec.temp_c - rec.temp_c[0]
    return np.column_stack([dt, dt * (pred - np.mean(pred))])


def _rate_unit(rec) -> np.ndarray:
    rate = rec.du_v_per_s
    return rate / max(float(np.max(np.abs(rate))), 1e-12)


BUILT_IN = (
    Signature(
        "gain changing with time",
        lambda r, p, c: np.column_stack([_time_s(r) * (p - np.mean(p)), _time_s(r)]),
        _gain_words,
        "time × displacement (s·µm)",
        nested=1,
    ),
    Signature("drift with time", lambda r, p, c: _time_s(r)[:, None], _drift_words, "time (s)"),
    Signature(
        "drive level squared",
        lambda r, p, c: np.column_stack([_drive_unit(r) ** 2, _drive_unit(r)]),
        _square_words,
        "drive level (−1…1 of its span)",
        nested=1,
    ),
    Signature("drive rate", lambda r, p, c: _rate_unit(r)[:, None], _rate_words, "drive rate (of its peak)"),
    Signature(
        "rate limit",
        lambda r, p, c: np.column_stack([_rate_unit(r) * np.abs(_rate_unit(r)), _rate_unit(r)]),
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
    q = _pool_factor(records)
    for rec, full in zip(records, residuals):
        res, rate = _pool(full, q), rec.sample_rate_hz / q
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


def _line_signatures(records, residuals) -> list[Signature]:
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


def _rows(rec) -> tuple[np.ndarray, np.ndarray]:
    """(training rows, unseen rows): the unseen are the held-out cycles and, outside the blocks, the
    rests and holds (the drive still: under 1 % of its typical rate). The moving stretches outside the
    blocks — the first cycle out of a rest, a ramp — are left out: their error is the loop's start-up,
    which the diagnosis's failures report."""
    train, held = np.zeros(rec.u_v.size, dtype=bool), np.zeros(rec.u_v.size, dtype=bool)
    for s in rec.splits:
        train[s.train[0] : s.train[1]] = True
        held[s.held_out[0] : s.held_out[1]] = True
    speed = np.abs(rec.du_v_per_s)
    still = speed <= STILL_RATE_SHARE * max(float(np.percentile(speed, 95)), 1e-300)
    return train, held | (still & ~train)


def _halves(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(stretch id, fold) for each of ``rows``' samples: every contiguous stretch of ``rows`` is cut in
    two halves, fold 0 and fold 1, each half a stretch of its own; so both folds hold a part of every
    held-out run, rest and hold."""
    index = np.flatnonzero(rows)
    stretch = np.cumsum(np.diff(index, prepend=-2) != 1) - 1
    starts = np.flatnonzero(np.diff(stretch, prepend=-1))
    lengths = np.diff(np.append(starts, index.size))
    position = np.arange(index.size) - np.repeat(starts, lengths)
    fold = (position >= np.repeat(lengths // 2, lengths)).astype(int)
    return 2 * stretch + fold, fold


def _centred(values: np.ndarray, stretch: np.ndarray) -> np.ndarray:
    """``values`` with each stretch (consecutive equal ids in ``stretch``) centred on its own mean: a
    stretch's level (a rest after a burst, a run of held-out cycles) carries the loop's memory, which no
    signature draws; what varies within it is what they describe."""
    starts = np.flatnonzero(np.diff(stretch, prepend=stretch[0] - 1))
    counts = np.diff(np.append(starts, stretch.size))
    means = np.add.reduceat(values, starts, axis=0) / (counts[:, None] if values.ndim == 2 else counts)
    return values - np.repeat(means, counts, axis=0)


def _solve(x: np.ndarray, y: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Least squares on columns scaled to unit RMS (``scale``), directions under 1 % of the largest
    singular value dropped: a column that is nearly still in one fold (the drive at a rest) must not
    give a wild coefficient that the other fold pays for."""
    return np.linalg.lstsq(x / scale, y, rcond=1e-2)[0] / scale


def _pool(values: np.ndarray, q: int) -> np.ndarray:
    """Means of ``q`` consecutive rows (the last group may be shorter)."""
    if q <= 1:
        return values
    starts = np.arange(0, values.shape[0], q)
    counts = np.diff(np.append(starts, values.shape[0]))
    return np.add.reduceat(values, starts, axis=0) / (counts[:, None] if values.ndim == 2 else counts)


def _pool_factor(records) -> int:
    """Samples pooled into one row (POOL_RATE_HZ at the slowest record's rate)."""
    return max(1, int(min(r.sample_rate_hz for r in records) // POOL_RATE_HZ))


def _judge(sig: Signature, records, residuals, predictions, ctx: dict, noise_um: float | None) -> dict | None:
    """Judge ``sig`` on the unseen rows by two-fold cross-validation over their stretches (each centred
    on its own mean): fitted on one fold, scored on the other, and back. The training rows are not used:
    there the model fitted the noise and bent its own error. Its coefficients, for the words, are
    fitted on all the unseen rows."""
    xs, ys, folds, figure_x = [], [], [], []
    q = _pool_factor(records)
    for rec, res, pred in zip(records, residuals, predictions):
        cols = sig.columns(rec, pred, ctx)
        train, unseen = ctx["rows"][id(rec)]
        if cols is None or unseen.sum() <= 2 * q * (cols.shape[1] + 1):
            continue
        stretch, fold = (v[::q] for v in _halves(unseen))
        x_unseen, y_unseen = _pool(cols[unseen], q), _pool(res[unseen], q)
        if sig.from_training:  # fold −1: the training cycles (fitted, never scored); fold 1: the unseen rows
            t_stretch = _halves(train)[0][::q]
            xs.append(_centred(_pool(cols[train], q), t_stretch))
            ys.append(_centred(_pool(res[train], q), t_stretch))
            folds.append(np.full(t_stretch.size, -1))
            fold = np.ones_like(fold)
        xs.append(_centred(x_unseen, stretch))
        ys.append(_centred(y_unseen, stretch))
        folds.append(fold)
        own = x_unseen[:, 0]
        if sig.name.startswith("line"):
            own = np.degrees(np.mod(np.arctan2(x_unseen[:, 0], x_unseen[:, 1]), 2 * np.pi))
        figure_x.append(own)
    if not xs:
        return None
    x, y, fold = np.vstack(xs), np.concatenate(ys), np.concatenate(folds)
    scale = np.maximum(np.sqrt(np.mean(x**2, axis=0)), 1e-300)
    scored = fold >= 0
    before = y[scored]
    after, reference = y.copy(), y.copy()  # reference: no signature, or its nested part
    base = slice(x.shape[1] - sig.nested, None)
    for k in (0, 1):
        fit, test = (fold != k) & ((fold == -1) if sig.from_training else True), fold == k
        if not test.any() or not fit.any():
            continue
        after[test] -= x[test] @ _solve(x[fit], y[fit], scale)
        if sig.nested:
            reference[test] -= x[test][:, base] @ _solve(x[fit][:, base], y[fit], scale[base])
    after, reference = after[scored], reference[scored]
    return {
        "sig": sig,
        "coef": _solve(x[fold == -1], y[fold == -1], scale) if sig.from_training else _solve(x, y, scale),
        "share": float(1.0 - np.sum(after**2) / max(float(np.sum(before**2)), 1e-300)),
        "excess_share": _excess_share(before, after, None if not noise_um else noise_um / np.sqrt(q)),
        "t": _gain_t(reference, after, None if not noise_um else noise_um / np.sqrt(q)),
        "gain_nm2": float(np.mean(before**2 - after**2) * 1e6),
        "figure": (np.concatenate(figure_x), before),
    }


def _excess_share(before: np.ndarray, after: np.ndarray, noise_um: float | None) -> float:
    """The share of the residual power above the gauge noise (σ = ``noise_um``) that the signature removes
    (the plain share when there is no noise figure, or no power above it)."""
    power = float(np.sum(before**2))
    excess = power - before.size * (noise_um or 0.0) ** 2
    return float((power - np.sum(after**2)) / (excess if excess > 0.05 * power else power))


def _gain_t(reference: np.ndarray, after: np.ndarray, noise_um: float | None) -> float:
    """How far the signature's held-out gain (the drop from ``reference`` to ``after``, µm) stands above
    what it would be on gauge noise of σ = ``noise_um``: z = Σ(ref² − after²) / (2σ·√Σ(ref − after)²).
    On white noise a regressor fitted elsewhere gains z ~ N(−, 1), however few the rows it touches, so a
    strong effect confined to one block is seen. Without a noise figure: the chunked t statistic."""
    change = reference - after
    if noise_um and noise_um > 0:
        spread = 2.0 * noise_um * np.sqrt(np.sum(change**2))
        return float(np.sum(reference**2 - after**2) / spread) if spread > 0 else 0.0
    return _chunked_t(reference**2 - after**2)


def _chunked_t(gain: np.ndarray) -> float:
    """The t statistic of a mean gain (µm²) over contiguous chunks of the unseen rows (their samples are
    correlated: a chunk's mean is nearly independent of the next's)."""
    means = np.array([c.mean() for c in np.array_split(gain, max(2, min(CHUNKS, gain.size // 200)))])
    spread = means.std(ddof=1) / np.sqrt(means.size)
    return float(means.mean() / spread) if spread > 0 else 0.0


def _figure(x: np.ndarray, y_um: np.ndarray, x_label: str) -> dict:
    step = max(1, x.size // FIGURE_POINTS)
    return {"x": x[::step].round(6).tolist(), "residual_nm": (1e3 * y_um[::step]).round(3).tolist(), "x_label": x_label}


def describe_remainder(records, residuals, predictions, noise_um: float | None = None) -> dict:
    """The residual the model leaves on the rows it never fitted, described by the signatures that
    explain a significant share of it (best first, at most TOP): each with that share, its t statistic,
    a sentence and a figure (the residual against the signature's own variable). ``tried`` lists every
    signature tested, so the Bonferroni threshold (``threshold_t``) can be checked. ``noise_um``: the
    gauge noise's σ (µm), from the diagnosis's noise floor; the test is against it (see ``_gain_t``)."""
    records, residuals, predictions = list(records), list(residuals), list(predictions)
    signatures = [*BUILT_IN, *_line_signatures(records, residuals)]
    ctx = {
        "duration_s": max(r.u_v.size / r.sample_rate_hz for r in records),
        "span_um": max(float(np.ptp(p)) for p in predictions),
        "frequencies_hz": sorted({f for r in records for s in r.splits if (f := axis_frequency_hz(s.block, r.axis))}),
        "rows": {id(r): _rows(r) for r in records},  # (training, unseen) per record
    }
    judged = [j for s in signatures if (j := _judge(s, records, residuals, predictions, ctx, noise_um)) is not None]
    threshold = NormalDist().inv_cdf(1 - FAMILY_ALPHA / max(len(judged), 1))
    found = sorted(
        (j for j in judged if j["t"] > threshold and j["excess_share"] >= MIN_SHARE), key=lambda j: -j["excess_share"]
    )
    q = _pool_factor(records)
    parts = [
        (_pool(res[rows], q), _halves(rows)[0][::q])
        for rec, res in zip(records, residuals)
        if (rows := ctx["rows"][id(rec)][1]).any()
    ]
    unseen = np.concatenate([_centred(values, stretch) for values, stretch in parts]) if parts else np.zeros(0)
    return {
        "unseen_rms_nm": float(1e3 * np.sqrt(np.mean(unseen**2))) if unseen.size else None,
        "unseen_samples": int(unseen.size),
        "threshold_t": float(threshold),
        "tried": [j["sig"].name for j in judged],
        "signatures": [
            {
                "signature": j["sig"].name,
                "share_of_residual": round(j["share"], 4),
                "share_of_excess": round(j["excess_share"], 4),
                "t": round(j["t"], 2),
                "gain_nm2": round(j["gain_nm2"], 4),
                "text": j["sig"].words(j["coef"], ctx),
                "figure": _figure(*j["figure"], j["sig"].x_label),
            }
            for j in found[:TOP]
        ],
    }


def remainder_words(remainder: dict | None) -> str:
    """The description's leading sentence for the verdict (empty when nothing is described)."""
    if not remainder or not remainder["signatures"]:
        return ""
    top = remainder["signatures"][0]
    return (
        f"; what remains, described: {top['text']} ({100 * top['share_of_excess']:.0f} % of the unseen residual "
        "above the noise)"
    )
