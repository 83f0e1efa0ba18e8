"""What remains, described: the residual a model leaves, read against a dictionary of physical
signatures, so that an effect the library cannot name is still described in a physicist's words.

The signatures are service.science.discovery.signature_dictionary's: time, time × displacement, the
drive level and its square, the rate, the error repeated per block, lines not locked to the drive,
the other axis, the temperature.

The same held-out discipline as the claims: a signature is judged only on rows the model never
fitted — the held-out cycles, and outside the blocks the rests and holds — by two-fold
cross-validation (every stretch cut into short chunks given to two folds in turn: fitted on one fold, scored on the other,
and back), against the gauge noise with a one-sided threshold corrected for the number of signatures tried (Bonferroni), so that a
signature is not read into noise. Units: residuals in µm in, nm in the texts; time in s; drive in V.
"""

from __future__ import annotations

from statistics import NormalDist

import numpy as np

from service.science.data.holdout import axis_frequency_hz
from service.science.discovery.rests import still_mask
from service.science.discovery.signature_dictionary import (
    BUILT_IN,
    Signature,
    line_signatures,
    pool,
    pool_factor,
)
from service.science.effects import EFFECTS

#: family-wise false-description rate over the signatures tried on one residual
FAMILY_ALPHA = 0.01
#: contiguous chunks the unseen rows are cut into for the gain's t-test without a noise figure
CHUNKS = 40
#: pooled rows a signature's columns are built for at a time (bounds their memory)
POOL_CHUNK_ROWS = 4096
#: signatures reported, best first
TOP = 3
#: pooled rows per chunk of the two-fold cross-validation's interleaved folds (_folds): 1.6 ms at 2500 Hz
FOLD_CHUNK_ROWS = 4
#: points of a signature's figure (the unseen rows, decimated evenly)
FIGURE_POINTS = 400
#: a signature is reported when it explains at least this share of what remains above the gauge noise
#: on the unseen rows: a reporting choice (below it the sentence would describe a sliver), not the test
MIN_SHARE = 0.05


def _rows(rec) -> tuple[np.ndarray, np.ndarray]:
    """(training rows, unseen rows): the unseen are the held-out cycles and, outside the blocks, the
    rests and holds (the drive still: under 1 % of its typical rate). The moving stretches outside the
    blocks — the first cycle out of a rest, a ramp — are left out: their error is the loop's start-up,
    which the diagnosis's failures report."""
    train, held = np.zeros(rec.u_v.size, dtype=bool), np.zeros(rec.u_v.size, dtype=bool)
    for s in rec.splits:
        train[s.train[0] : s.train[1]] = True
        held[s.held_out[0] : s.held_out[1]] = True
    return train, held | (still_mask(rec) & ~train)


def _folds(rows: np.ndarray, q: int) -> tuple[np.ndarray, np.ndarray]:
    """(stretch id, fold) for each of ``rows``' samples: every contiguous stretch of ``rows`` is one
    stretch, cut into chunks of FOLD_CHUNK_ROWS pooled rows (``q`` samples each) given to folds 0 and 1
    in turn, so both folds hold every branch of every held-out cycle, rest and hold. Halves (fold 0 the
    first half of a stretch) put a one-cycle stretch's rising branch in one fold and its falling branch
    in the other: a gain fitted on one branch was scored on the other, and a gain that changed through
    each block (a stack heated by its drive) was read as nothing. The gauge noise is white, so the folds'
    noises stay independent and the test still refuses to read a signature into noise."""
    index = np.flatnonzero(rows)
    stretch = np.cumsum(np.diff(index, prepend=-2) != 1) - 1
    starts = np.flatnonzero(np.diff(stretch, prepend=-1))
    lengths = np.diff(np.append(starts, index.size))
    position = np.arange(index.size) - np.repeat(starts, lengths)
    fold = ((position // (FOLD_CHUNK_ROWS * max(q, 1))) % 2).astype(int)
    return stretch, fold


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


def _pooled_columns(sig: Signature, rec, pred, ctx: dict, rows: np.ndarray, q: int) -> np.ndarray | None:
    """``sig``'s columns on ``rows``, pooled by ``q``, built a chunk of rows at a time (a multiple of
    ``q``, so the pools are the same): the per-block columns over every row would take 0.1 GB a sweep."""
    chunk = q * POOL_CHUNK_ROWS
    pooled = []
    for at in range(0, rows.size, chunk):
        part = sig.columns(rec, pred, ctx, rows[at : at + chunk])
        if part is None:
            return None
        pooled.append(pool(part, q))
    return np.vstack(pooled) if pooled else None


def _judge(sig: Signature, records, residuals, predictions, ctx: dict, noise_um: float | None) -> dict | None:
    """Judge ``sig`` on the unseen rows by two-fold cross-validation over their stretches (each centred
    on its own mean): fitted on one fold, scored on the other, and back. The training rows are not used:
    there the model fitted the noise and bent its own error. Its coefficients, for the words, are
    fitted on all the unseen rows."""
    xs, ys, folds, figure_x = [], [], [], []
    q = pool_factor(records)
    for rec, res, pred in zip(records, residuals, predictions):
        train, unseen = ctx["rows"][id(rec)]
        x_unseen = _pooled_columns(sig, rec, pred, ctx, np.flatnonzero(unseen), q)
        if x_unseen is None or x_unseen.shape[0] <= 2 * (x_unseen.shape[1] + 1):
            continue
        stretch, fold = (v[::q] for v in _folds(unseen, q))
        y_unseen = pool(res[unseen], q)
        if sig.from_training:  # fold −1: the training cycles (fitted, never scored); fold 1: the unseen rows
            t_stretch = _folds(train, q)[0][::q]
            xs.append(_centred(_pooled_columns(sig, rec, pred, ctx, np.flatnonzero(train), q), t_stretch))
            ys.append(_centred(pool(res[train], q), t_stretch))
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
    signatures = [*BUILT_IN, *line_signatures(records, residuals)]
    ctx = {
        "duration_s": max(r.u_v.size / r.sample_rate_hz for r in records),
        "span_um": max(float(np.ptp(p)) for p in predictions),
        "frequencies_hz": sorted({f for r in records for s in r.splits if (f := axis_frequency_hz(s.block, r.axis))}),
        "rows": {id(r): _rows(r) for r in records},  # (training, unseen) per record
        # the rate words name the amplifier only where a rate limit's own rule lets it act here
        "amplifier_can_limit": any(e.limits_rate and e.untestable(records) is None for e in EFFECTS.values()),
    }
    judged = [j for s in signatures if (j := _judge(s, records, residuals, predictions, ctx, noise_um)) is not None]
    threshold = NormalDist().inv_cdf(1 - FAMILY_ALPHA / max(len(judged), 1))
    found = sorted(
        (j for j in judged if j["t"] > threshold and j["excess_share"] >= MIN_SHARE), key=lambda j: -j["excess_share"]
    )
    q = pool_factor(records)
    parts = [
        (pool(res[rows], q), _folds(rows, q)[0][::q])
        for rec, res in zip(records, residuals)
        if (rows := ctx["rows"][id(rec)][1]).any()
    ]
    unseen = np.concatenate([_centred(values, stretch) for values, stretch in parts]) if parts else np.zeros(0)
    shares = [round(min(j["excess_share"], 1.0), 4) for j in found[:TOP]]
    return {
        "unseen_rms_nm": float(1e3 * np.sqrt(np.mean(unseen**2))) if unseen.size else None,
        "unseen_samples": int(unseen.size),
        "threshold_t": float(threshold),
        "tried": [j["sig"].name for j in judged],
        "signatures": [
            {
                "signature": j["sig"].name,
                "share_of_residual": round(j["share"], 4),
                "share_of_excess": share,  # more than all: noise fitted too
                "t": round(j["t"], 2),
                "gain_nm2": round(j["gain_nm2"], 4),
                "text": j["sig"].words(j["coef"], ctx),
                "figure": _figure(*j["figure"], j["sig"].x_label),
            }
            for j, share in zip(found[:TOP], shares)
        ],
        "shares_overlap": sum(shares) > 1.0,
        "shares_text": shares_words(shares),
    }


def shares_words(shares: list[float]) -> str:
    """What the signatures' shares (0–1 each, of one whole: the unseen residual above the noise) are:
    each is what its signature explains fitted alone, so two whose variables overlap describe part of
    the same residual; where they sum to more than the whole, the words say so (99.2 % and 11.3 % were
    printed side by side as if parts of it). Empty for fewer than two."""
    if len(shares) < 2:
        return ""
    total = 100 * sum(shares)
    words = (
        "Each share is of the same whole, the unseen residual above the noise, with its signature fitted "
        "alone: the descriptions overlap where their variables do"
    )
    return words + (
        f", so the shares sum to {total:.1f} %, more than the whole; they are not parts of it."
        if total > 100.0
        else f" (the shares sum to {total:.1f} %)."
    )
