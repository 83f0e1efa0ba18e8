"""Step-holds of an imported record: a drive held still at one level after another.

A lab's step-hold (0 → 96 → 24 → 120 → 48 → 84 → 0 V, each held half a second) is not an oscillation,
and its holds are not rests: each level reached after a step is the stage's answer to it, a point of
a reversal curve the sines may never draw (the rise from 48 V to 84 V after 120 V is a minor loop).
``step_blocks`` makes each level a block of kind "step" (the step into it and its hold), as a sweep
of this bench records its own steps (service.science.data.plans): the first 80 % trains and the rest
of the hold is held out (service.science.data.holdout). A stretch is a step-hold when its drive holds
at least MIN_STEP_LEVELS distinct levels; a rest between two bursts (one level) or a single offset
hold stays outside every block. The same rule reads a long record's stretches between its periodic
blocks and a one-file-per-block record's step file, so that both forms fit the same samples. Pure
numpy: sample indices and volts.
"""

from __future__ import annotations

import numpy as np

#: still (a rest or a hold): the drive within this share of its span over a window of this many
#: seconds centred on the sample (a 1 Hz sine's peak moves 2.4 % of its span over ±50 ms)
HOLD_SPAN_SHARE = 0.002
HOLD_WINDOW_S = 0.1
#: two holds are at distinct levels when they differ by more than this share of the drive's span
LEVEL_SHARE = 0.01
#: a hold shorter than this is not a level of a step-hold (s)
MIN_HOLD_S = 0.05
#: a stretch is a step-hold when it holds at least this many distinct levels (its rest counted)
MIN_STEP_LEVELS = 3


def held_still(u_v: np.ndarray, sample_rate_hz: float) -> np.ndarray:
    """Rows where the drive ``u_v`` (V) is held still: within HOLD_SPAN_SHARE of its span over the
    HOLD_WINDOW_S centred on the row."""
    from scipy.ndimage import maximum_filter1d, minimum_filter1d

    u = np.asarray(u_v, dtype=float)
    size = max(3, int(HOLD_WINDOW_S * sample_rate_hz) | 1)
    spread = maximum_filter1d(u, size, mode="nearest") - minimum_filter1d(u, size, mode="nearest")
    return spread <= HOLD_SPAN_SHARE * max(float(np.ptp(u)), 1e-12)


def _holds(still: np.ndarray, start: int, stop: int, min_samples: int) -> list[tuple[int, int]]:
    """(start, stop) of the runs of ``still`` rows in start..stop at least ``min_samples`` long."""
    inside = np.concatenate([[False], still[start:stop], [False]])
    edges = np.flatnonzero(np.diff(inside.astype(np.int8)))
    runs = zip(edges[::2] + start, edges[1::2] + start)
    return [(int(a), int(b)) for a, b in runs if b - a >= min_samples]


def step_blocks(
    u_v: np.ndarray, sample_rate_hz: float, start: int, stop: int, axes: list[str], still: np.ndarray | None = None
) -> list[dict]:
    """The step-hold in samples start..stop of drive ``u_v`` (V) as blocks, one per level after the
    first hold (from the end of the hold before it to the end of its own hold; kind "step",
    ``level_v``, no frequency or cycles, ``axes``); [] when the stretch holds fewer than
    MIN_STEP_LEVELS distinct levels. Blocks are in time order; ``index`` is left to the caller.
    ``still``: ``held_still`` of the whole drive, when the caller reads several stretches of it."""
    u = np.asarray(u_v, dtype=float)
    span = max(float(np.ptp(u)), 1e-12)
    still = held_still(u, sample_rate_hz) if still is None else still
    holds = _holds(still, start, stop, max(2, int(MIN_HOLD_S * sample_rate_hz)))
    # a hold the window cut in two (noise on a long hold) is one level with the hold before it
    levels, merged = [], []
    for a, b in holds:
        level = float(np.median(u[a:b]))
        if merged and abs(level - levels[-1]) <= LEVEL_SHARE * span:
            merged[-1] = (merged[-1][0], b)
            continue
        levels.append(level)
        merged.append((a, b))
    distinct = []
    for level in levels:
        if all(abs(level - other) > LEVEL_SHARE * span for other in distinct):
            distinct.append(level)
    if len(distinct) < MIN_STEP_LEVELS:
        return []
    return [
        {
            "index": 0,
            "start": merged[k - 1][1],
            "stop": merged[k][1],
            "kind": "step",
            "frequency_hz": None,
            "cycles": None,
            "level_v": levels[k],
            "axes": list(axes),
        }
        for k in range(1, len(merged))
    ]
