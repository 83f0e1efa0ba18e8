"""Blocks of an imported record: where each axis's drive oscillates at a steady period.

A characterisation exported without its block table (one CSV of a 1/10/50/100 Hz sweep, each axis
in turn) must still be validated per frequency: held out are the last cycles *of each block*, not
the last 20 % of the file (which would be one axis at rest). ``detect_blocks`` finds runs of
turning points of the drive with a steady spacing (each half period within 20 % of the run's
median), at least two whole cycles long, and returns them as sweep-style blocks; runs that
coincide on both axes (driven together) become one block with both axes. Holds, ramps between
levels and irregular stretches fall outside every block.
"""
from __future__ import annotations

import numpy as np

from service.science.data.signals import STEADY_HALF_PERIOD_SHARE, longest_linked_run, turning_points

#: successive mid-level crossings of one steady run are one period apart within this share
CROSSING_SHARE = 0.03
#: a run needs at least this many whole cycles to be a block
MIN_CYCLES = 2


def steady_runs(u: np.ndarray, sample_rate_hz: float) -> list[dict]:
    """Runs of steady oscillation of one drive: [{"start", "stop", "frequency_hz", "cycles"}]
    (sample indices; start at a turning point, whole cycles)."""
    u = np.asarray(u, dtype=float)
    tp = turning_points(u)
    half = np.diff(tp).astype(float)
    runs, i = [], 0
    while i < half.size:
        ref = float(np.median(half[i:i + 5]))          # the run's half period, from its first few
        j = i
        while j < half.size and abs(half[j] - ref) <= STEADY_HALF_PERIOD_SHARE * ref:
            j += 1
        if j - i >= 2 * MIN_CYCLES:                     # half periods i..j-1: turning points i..j
            half_period = int(round((tp[j] - tp[i]) / (j - i)))   # a half period of margin each side
            a = max(0, tp[i] - half_period, tp[i - 1] if i > 0 else 0)
            b = min(u.size, tp[j] + half_period + 1, tp[j + 1] + 1 if j + 1 < tp.size else u.size)
            run = _whole_cycles(u[a:b], a, 2.0 * half_period, mid=0.5 * (u[tp[i]:tp[j] + 1].min() + u[tp[i]:tp[j] + 1].max()))
            if run["cycles"] >= MIN_CYCLES:
                runs.append({**run, "frequency_hz": sample_rate_hz / run["period"]})
        i = max(j, i + 1)
    return [{k: v for k, v in r.items() if k != "period"} for r in runs]


def _whole_cycles(u: np.ndarray, offset: int, period: float, mid: float) -> dict:
    """Start, stop, cycles and period (samples) of a steady stretch, timed by its upward crossings of
    the mid level (interpolated: far sharper than the turning points, where the drive is flat and
    noise moves the extremum by many samples); ``mid`` is the steady part's mid level."""
    k = np.flatnonzero((u[:-1] < mid) & (u[1:] >= mid))
    crossings = _steady_chain(k + (mid - u[k]) / (u[k + 1] - u[k]), period)
    if crossings.size >= 3:
        # to 1e-6 samples: a whole number of samples stays whole (the cycle and harmonic analyses
        # need it exactly) whatever the drive's offset or units did to the interpolation's last bits
        period = round(float(crossings[-1] - crossings[0]) / (crossings.size - 1), 6)
        start = offset + int(np.ceil(crossings[0]))
        cycles = crossings.size - 1
    else:
        start, cycles = offset, int(np.floor((u.size - 1) / period + 1e-9))
    return {"start": int(start), "stop": int(round(start + cycles * period)), "cycles": int(cycles), "period": period}


def _steady_chain(crossings: np.ndarray, period: float) -> np.ndarray:
    """The longest run of successive crossings one period apart (within CROSSING_SHARE: interpolated
    crossings of a steady drive repeat to a small fraction of a sample)."""
    if crossings.size < 2:
        return crossings
    run = longest_linked_run(np.abs(np.diff(crossings) - period) <= CROSSING_SHARE * period)
    return crossings[:1] if run is None else crossings[run[0]:run[1]]


def detect_blocks(drives_v: dict[str, np.ndarray], sample_rate_hz: float) -> list[dict]:
    """Sweep-style blocks (index, start, stop, kind "detected", cycles, frequency_hz, axes) of the
    steady oscillations of every axis's drive, in time order; runs of two axes that overlap by more
    than half of the shorter one are one block driving both."""
    found = [(axis, run) for axis, u in drives_v.items() for run in steady_runs(u, sample_rate_hz)]
    found.sort(key=lambda item: item[1]["start"])
    blocks: list[dict] = []
    for axis, run in found:
        for block in blocks:
            overlap = min(block["stop"], run["stop"]) - max(block["start"], run["start"])
            if axis not in block["axes"] and overlap > 0.5 * min(block["stop"] - block["start"],
                                                                  run["stop"] - run["start"]):
                block["axes"].append(axis)
                break
        else:
            blocks.append({**run, "kind": "detected", "axes": [axis]})
    for index, block in enumerate(blocks):
        block["index"] = index
    return blocks


#: why a stretch of an imported record is in no block (it stays in the record: models run through it)
OUTSIDE_BLOCKS = ("not steady oscillation (a rest, a ramp, or the first cycle out of a rest, before the "
                  "oscillation is steady): outside the blocks")


def blocks_without_table(drives_v: dict[str, np.ndarray], sample_rate_hz: float) -> list[dict]:
    """The block table of a record that came without one: its steady stretches when there are several
    (a sweep over frequencies or axes, bursts between holds); else one block over the whole record,
    with the frequency and whole cycles of its one steady oscillation if it has one; and if a rest
    of more than one period comes before or after that oscillation, the block is the oscillation
    alone and ``trimmed`` says how long the rest was (s) before and after it. With several blocks,
    each block's ``trimmed`` gives the stretch between the previous block (or the record's start)
    and it, and the last block's also the stretch after it: what no block holds is reported."""
    blocks = detect_blocks(drives_v, sample_rate_hz)
    n = len(next(iter(drives_v.values())))
    if len(blocks) >= 2:
        previous_stop = 0
        for k, block in enumerate(blocks):
            after = n - int(block["stop"]) if k == len(blocks) - 1 else 0
            block["trimmed"] = {"before_s": max(0, int(block["start"]) - previous_stop) / sample_rate_hz,
                                "after_s": after / sample_rate_hz, "why": OUTSIDE_BLOCKS}
            previous_stop = max(previous_stop, int(block["stop"]))
        return blocks
    whole = {"index": 0, "start": 0, "stop": n, "kind": "imported", "frequency_hz": None, "cycles": None,
             "axes": list(drives_v)}
    if blocks:
        run = blocks[0]
        f = float(run["frequency_hz"])
        period = sample_rate_hz / f
        before, after = int(run["start"]), n - int(run["stop"])
        if max(before, after) > period:   # a rest (or a ramp) around the excitation: the block is the
            # steady oscillation alone, so its cycles and held-out cycles are the drive's own; the
            # rest stays in the record (the model runs through it) and is reported
            return [{**whole, "start": int(run["start"]), "stop": int(run["stop"]), "frequency_hz": f,
                     "cycles": int(run["cycles"]), "axes": run["axes"],
                     "trimmed": {"before_s": before / sample_rate_hz, "after_s": after / sample_rate_hz,
                                 "why": OUTSIDE_BLOCKS}}]
        whole.update(frequency_hz=f, cycles=int(np.floor(n * f / sample_rate_hz + 1e-9)), axes=run["axes"])
    return [whole]
