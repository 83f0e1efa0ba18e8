"""When a candidate effect is claimed: a held-out comparison with a stated false-claim basis.

The comparison is between two fitted models, a *reference* and the reference plus the candidate,
on the held-out cycles only (never fitted), each block's residual less its mean over the last
training cycle (the vertical position of a block's loop is history the base may get wrong; what a
candidate must explain is what changes after the training cycles). Each held-out stretch is cut into segments of about
an eighth of a cycle (a 64th of a non-periodic stretch); per segment, the improvement is the drop
in mean squared residual. A candidate is **claimed** when both hold:

1. **significance**: a one-sided Wilcoxon signed-rank test of the segment improvements gives
   p < ``FAMILY_ALPHA`` / (the number of candidates the diagnosis tests) (a candidate that only fits noise improves held-out segments as often, and by as
   much, as it worsens them; ranks, not means, so that a real effect concentrated in the fast
   blocks is not drowned by the variance of the slow ones), each block's level anchored at its last
   training cycle: a family without wiping-out memory comes to rest elsewhere, block after block,
   which is history, not a time effect;
2. **size**: the mean held-out improvement is at least ``NOISE_MULTIPLE`` noise variances σ²
   (σ: the noise floor measured from the data's own cycle-to-cycle scatter). An effect smaller
   than the noise cannot be seen to fall and is not claimed. The size is the larger of the
   improvement with that anchor and with each block's level anchored at the mean of its training
   cycles: a slow effect *is* a change of level, most of it inside the training cycles, which the
   last-cycle anchor removes — on the yan9a-dbo record creep takes the held-out RMS from 0.238 to
   0.129 µm, 4.0e4 nm² of mean square at the training mean, 1.7e3 nm² at the last cycle (σ² =
   4.3e3 nm²). The training-mean anchor still removes what differs between blocks (their rest
   positions), which a polynomial in time would otherwise fit: on a foreign Bouc–Wen stage with
   gaps between its bursts, drift was claimed after creep when the size was taken as measured.

The reference is what keeps *systematic* misfit from being claimed: for a physical candidate it is
the model plus a flexible rate-independent base (finer operators and a non-symmetric loop shape),
so that a loop shape the paper's PI cannot draw is never called physics. The false-claim rate of
this rule on clean benches of several hysteresis families is measured by
``python -m service.reports.discovery_matrix`` and stated in docs/discovery-evidence.md.
Pure numpy/scipy: no store, no HTTP.
"""

from __future__ import annotations

import numpy as np

from service.science.data.units import fmt_nm2

#: family-wise false-claim rate of one diagnosis: the chance that any candidate it tests is claimed on a
#: stage that lacks it, split evenly over the candidates tested (Bonferroni: ``candidate_alpha``), so that
#: a larger library (plug-ins, new built-ins) does not raise the rate at which a diagnosis claims falsely
FAMILY_ALPHA = 0.01
#: one-sided significance level of the held-out improvement of one candidate tested alone
ALPHA = 1e-3
#: the improvement must be at least this many noise variances of held-out mean square
NOISE_MULTIPLE = 1.0
SEGMENTS_PER_CYCLE = 8
SEGMENTS_PER_STRETCH = 64
#: a segment whose two mean squares differ by at most this share of their sum is a tie, dropped from
#: the signed-rank test as an exact tie is: two fits that agree on a block (a block driving only the
#: other axis, an effect whose columns are zero there) differ there by rounding alone, measured at
#: ≤ 1e-12 of the mean square, while the smallest real difference seen was 1e-8 (default, creep,
#: delay and Bouc–Wen benches). Counted, rounding's signs changed p with the order of a sum.
TIE_SHARE = 1e-10


def _segments(rec, split) -> list[tuple[int, int]]:
    a, b = split.held_out
    period = rec.period_samples(split)
    n = max(1, int(round((b - a) / (period / SEGMENTS_PER_CYCLE)))) if period else SEGMENTS_PER_STRETCH
    n = min(n, max(1, (b - a) // 4))
    edges = np.linspace(a, b, n + 1).round().astype(int)
    return [(int(s), int(e)) for s, e in zip(edges[:-1], edges[1:]) if e > s]


def _held_out_less_mean(residual: np.ndarray, split, start: int) -> np.ndarray:
    """The block's held-out residual (rows ``split.held_out``) less its mean over training rows
    ``start``..the end of training (a slice, not a copy of the whole record: a diagnosis takes it
    about 500 times)."""
    a, b = split.held_out
    cut = split.train[1]
    held = residual[a:b]
    return held - float(np.mean(residual[start:cut])) if cut > start else held


def training_mean_free(residual: np.ndarray, split) -> np.ndarray:
    """The held-out residual less its mean over the block's training rows (the level the fit itself sets)."""
    return _held_out_less_mean(residual, split, split.train[0])


def _offset_free(residual: np.ndarray, rec, split) -> np.ndarray:
    """The held-out residual less its mean over the block's last training cycle (the last fifth of the
    training rows of a non-periodic block): where the loop sits vertically in one block is history
    the base may get wrong (a Bouc–Wen or Maxwell-slip stack has no wiping-out memory, so it comes to
    rest elsewhere than a Preisach model predicts); a candidate must explain what changes *after*
    the training cycles — the held-out ones come last."""
    a, cut = split.train
    period = rec.period_samples(split)
    return _held_out_less_mean(residual, split, max(a, cut - int(round(period)) if period else cut - (cut - a) // 5))


def held_out_improvement(records, res_ref, res_trial) -> dict:
    """Segment-wise held-out improvement of a trial model over a reference (residuals per record,
    µm): ``gain_mse_um2`` (mean over held-out stretches of the drop in mean square, every block
    weighted alike, levels anchored at the last training cycle), ``gain_trend_mse_um2`` (the same
    with levels anchored at the block's training mean), ``p`` (one-sided signed-rank over the
    segments, anchored as the larger of the two sizes is: the p is of the figure the size is; a
    segment within ``TIE_SHARE`` of no change is a tie and left out), ``p_anchor`` ("last_cycle" or
    "training_mean"), ``segments`` (those counted), and ``reference_mse_um2`` /
    ``reference_trend_mse_um2``: the reference's own held-out mean square at each anchoring, averaged
    alike, the whole each drop is a part of. With the p always at the last training cycle,
    a slow effect whose size is its level was sized at one anchor and tested at the other: creep on
    the default bench's quick sweep, 142 nm² at the training mean (p = 0.00053) and 29.4 nm² at the
    last cycle (p = 0.0032), was never claimed, and drift (p = 0.31 at the training mean) took it."""
    diffs, gains, trend_gains = {"last_cycle": [], "training_mean": []}, [], []
    wholes, trend_wholes = [], []
    for rec, r0, r1 in zip(records, res_ref, res_trial):
        for s in rec.splits:
            a, b = s.held_out
            if b - a < 2:
                continue
            e0, e1 = _offset_free(r0, rec, s), _offset_free(r1, rec, s)  # the held-out rows a..b
            gains.append(float(np.mean(e0**2) - np.mean(e1**2)))
            m0, m1 = training_mean_free(r0, s), training_mean_free(r1, s)
            trend_gains.append(float(np.mean(m0**2) - np.mean(m1**2)))
            wholes.append(float(np.mean(e0**2)))
            trend_wholes.append(float(np.mean(m0**2)))
            for i, j in _segments(rec, s):
                for anchor, (f0, f1) in (("last_cycle", (e0, e1)), ("training_mean", (m0, m1))):
                    ms0, ms1 = float(np.mean(f0[i - a : j - a] ** 2)), float(np.mean(f1[i - a : j - a] ** 2))
                    if abs(ms0 - ms1) > TIE_SHARE * (ms0 + ms1):
                        diffs[anchor].append(ms0 - ms1)
    from scipy import stats  # imported when used: scipy.stats costs a service 0.4 s of start-up

    gain = float(np.mean(gains)) if gains else 0.0
    trend_gain = float(np.mean(trend_gains)) if trend_gains else 0.0
    anchor = "training_mean" if trend_gain > gain else "last_cycle"
    d = np.asarray(diffs[anchor])
    p = 1.0 if d.size < 2 or not gains else float(stats.wilcoxon(d, alternative="greater").pvalue)
    return {
        "gain_mse_um2": gain,
        "gain_trend_mse_um2": trend_gain,
        "p": p,
        "p_anchor": anchor,
        "segments": int(d.size),
        "reference_mse_um2": float(np.mean(wholes)) if wholes else 0.0,
        "reference_trend_mse_um2": float(np.mean(trend_wholes)) if trend_wholes else 0.0,
    }


def less_gain_change(records, residuals) -> list[np.ndarray]:
    """Each record's residual (µm) less a gain that changes linearly with time: the columns
    t·(x − x̄) and x − x̄ (t in s from the record's start, x the measured displacement) fitted on the
    record's training rows only. A stack whose gain falls 0.1 % a second (depolarisation, self-heating)
    leaves −g·(t − t̄)·x once the fit has taken its mean gain, and creep's slow lags drew part of it
    (a foreign Bouc–Wen stage: creep claimed at p = 4.5e-10); a time effect is claimed for what it
    explains beyond such a gain."""
    out = []
    for rec, res in zip(records, residuals):
        train = np.zeros(rec.n_samples, dtype=bool)
        for s in rec.splits:
            train[s.train[0] : s.train[1]] = True
        x = rec.x_um - float(np.mean(rec.x_um))
        cols = np.column_stack([rec.t_s * x, x])
        if train.sum() <= cols.shape[1]:
            out.append(res)
            continue
        coef = np.linalg.lstsq(cols[train], res[train], rcond=None)[0]
        out.append(res - cols @ coef)
    return out


def unseen_block_improvement(records, res_ref, res_trial, frequency_hz: float) -> list[float]:
    """Per block at ``frequency_hz`` of the records' own axis (blocks neither model was fitted on),
    the drop in mean square (µm²) from the reference's residual to the trial's over the whole
    block, each less its own mean (where a block's loop sits is history, as above)."""
    gains = []
    for rec, r0, r1 in zip(records, res_ref, res_trial):
        for s in rec.splits_of(own_axis_only=True):
            if s.block.get("frequency_hz") != frequency_hz:
                continue
            a, b = s.train[0], s.held_out[1]
            e0, e1 = r0[a:b] - np.mean(r0[a:b]), r1[a:b] - np.mean(r1[a:b])
            gains.append(float(np.mean(e0**2) - np.mean(e1**2)))
    return gains


def candidate_alpha(candidates: int) -> float:
    """The significance level (one-sided p) each of ``candidates`` tested in one diagnosis must pass:
    FAMILY_ALPHA split over them (Bonferroni; 0.01 / 9 = 1.1e-3 for the ten built-ins less the base)."""
    return FAMILY_ALPHA / max(int(candidates), 1)


def claimed(test: dict, noise_um: float, alpha: float = ALPHA) -> bool:
    """The rule above: significant (p < ``alpha``, the diagnosis's ``candidate_alpha``) and at least
    NOISE_MULTIPLE·σ² of held-out mean square, the size with the levels anchored at the last training
    cycle or at the training mean (the larger)."""
    size = max(test["gain_mse_um2"], test.get("gain_trend_mse_um2", test["gain_mse_um2"]))
    return bool(test["p"] < alpha and size >= NOISE_MULTIPLE * noise_um**2)


def rule_text(noise_um: float, candidates: int = 1) -> str:
    alpha = candidate_alpha(candidates)
    return (
        f"claimed when the held-out improvement over the reference is significant (one-sided signed-rank test over "
        f"held-out segments, p < {alpha:.2g}: a family-wise {FAMILY_ALPHA:g} over the {candidates} candidates "
        f"tested, Bonferroni) and at least {NOISE_MULTIPLE:g}σ² = "
        f"{fmt_nm2(NOISE_MULTIPLE * noise_um**2)} of mean square, with each block's level anchored at its "
        f"last training cycle or at its training mean (the larger)"
    )
