"""Blocks of an imported record: where each axis's drive oscillates at a steady period.

A characterisation exported without its block table (one CSV of a 1/10/50/100 Hz sweep, each axis
in turn) must still be validated per frequency: held out are the last cycles *of each block*, not
the last 20 % of the file (which would be one axis at rest). ``detect_blocks`` finds runs of
turning points of the drive with a steady spacing (each half period within 20 % of the run's
median) and steady levels (each within 5 % of the swing of the one a cycle before), at least two
whole cycles long, and returns them as sweep-style blocks; runs that
coincide on both axes (driven together) become one block with both axes. Holds, ramps between
levels and irregular stretches fall outside every block.
"""

from __future__ import annotations

import math

import numpy as np

from service.science.data.signals import STEADY_HALF_PERIOD_SHARE, longest_linked_run, turning_points
from service.science.data.steps import held_still, step_blocks

#: successive mid-level crossings of one steady run are one period apart within this share
CROSSING_SHARE = 0.03
#: a run needs at least this many whole cycles to be a block
MIN_CYCLES = 2
#: a steady oscillation repeats: each turning point within this share of the run's first swing of the
#: one a cycle before (a step-hold's levels, 96/24/120/48/84 V a half second apart, have a steady
#: spacing but are not cycles: read as a 1 Hz block they put a frequency into the record that no
#: drive had; a drive's own noise moves a turning point by far less)
REPEAT_LEVEL_SHARE = 0.05
#: runs of two axes at frequencies this close (share of the higher) are one oscillation on both
SAME_FREQUENCY_SHARE = 0.01
#: simultaneous runs at different frequencies repeat together if each ratio to the slowest is p/q,
#: q at most this, within JOINT_RATIO_SHARE of p/q
MAX_JOINT_DENOMINATOR = 12
JOINT_RATIO_SHARE = 1e-3


def steady_runs(u: np.ndarray, sample_rate_hz: float) -> list[dict]:
    """Runs of steady oscillation of one drive: [{"start", "stop", "frequency_hz", "cycles"}]
    (sample indices; start at a turning point, whole cycles)."""
    u = np.asarray(u, dtype=float)
    tp = turning_points(u)
    half = np.diff(tp).astype(float)
    levels = u[tp]
    runs, i = [], 0
    while i < half.size:
        ref = float(np.median(half[i : i + 5]))  # the run's half period, from its first few
        swing = abs(levels[i + 1] - levels[i])
        j = i
        while (
            j < half.size
            and abs(half[j] - ref) <= STEADY_HALF_PERIOD_SHARE * ref
            and (j == i or abs(levels[j + 1] - levels[j - 1]) <= REPEAT_LEVEL_SHARE * swing)
        ):
            j += 1
        if j - i >= 2 * MIN_CYCLES:  # half periods i..j-1: turning points i..j
            half_period = int(round((tp[j] - tp[i]) / (j - i)))  # a half period of margin each side
            a = max(0, tp[i] - half_period, tp[i - 1] if i > 0 else 0)
            b = min(u.size, tp[j] + half_period + 1, tp[j + 1] + 1 if j + 1 < tp.size else u.size)
            run = _whole_cycles(
                u[a:b], a, 2.0 * half_period, mid=0.5 * (u[tp[i] : tp[j] + 1].min() + u[tp[i] : tp[j] + 1].max())
            )
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
    crossings of a steady drive repeat to a small fraction of a sample), less an end crossing that
    is off the line through the others (``_off_line_ends``)."""
    if crossings.size < 2:
        return crossings
    run = longest_linked_run(np.abs(np.diff(crossings) - period) <= CROSSING_SHARE * period)
    return crossings[:1] if run is None else _off_line_ends(crossings[run[0] : run[1]])


#: an end crossing is dropped when it lies further off the line through the others than this many
#: times their RMS distance from it (and more than END_CROSSING_FLOOR samples)
END_CROSSING_SPREAD = 5.0
END_CROSSING_FLOOR = 1e-3


def _off_line_ends(chain: np.ndarray) -> np.ndarray:
    """``chain`` without end crossings that the drive's end made (a burst cut off before its last
    crossing, then the rest level: the 'crossing' lands on the first sample of the rest, a third of
    a sample early at 3 Hz and 5 kHz, and put the period 0.005 % short, which successive cycles of a
    steep loop showed as 9–15 nm of 'noise')."""
    while chain.size >= 4:
        k = np.arange(chain.size)
        inner = slice(1, -1)
        slope, offset = np.polyfit(k[inner], chain[inner], 1)
        spread = float(np.sqrt(np.mean((chain[inner] - (slope * k[inner] + offset)) ** 2)))
        ends = np.abs(chain[[0, -1]] - (slope * k[[0, -1]] + offset))
        worst = int(np.argmax(ends))
        if ends[worst] <= max(END_CROSSING_SPREAD * spread, END_CROSSING_FLOOR):
            return chain
        chain = chain[1:] if worst == 0 else chain[:-1]
    return chain


def detect_blocks(drives_v: dict[str, np.ndarray], sample_rate_hz: float) -> list[dict]:
    """Sweep-style blocks (index, start, stop, kind "detected", cycles, frequency_hz, axes) of the
    steady oscillations of every axis's drive, in time order and never overlapping. Runs of two axes
    at one frequency that overlap by more than half of the shorter one are one block driving both.
    Runs that overlap otherwise (one axis swept while the other oscillates steadily at its own
    frequency) are cut where each starts and stops: each stretch is a block of the axes driven
    there, with ``frequencies_hz`` per axis and the frequency at which they repeat together
    (``joint_frequency_hz``; None if they do not), so that every block is whole cycles of its drive."""
    found = sorted(
        ((axis, run) for axis, u in drives_v.items() for run in steady_runs(u, sample_rate_hz)),
        key=lambda item: (item[1]["start"], item[1]["stop"]),
    )
    blocks: list[dict] = []
    for cluster in _overlapping(found):
        blocks += _one_oscillation(cluster) or _stretches(cluster, sample_rate_hz)
    blocks.sort(key=lambda block: block["start"])
    for index, block in enumerate(blocks):
        block["index"] = index
    return blocks


def _overlapping(found: list) -> list[list]:
    """``found`` (axis, run) in start order, grouped into chains of runs that overlap in time."""
    clusters: list[list] = []
    reach = 0
    for axis, run in found:
        if clusters and run["start"] < reach:
            clusters[-1].append((axis, run))
            reach = max(reach, run["stop"])
        else:
            clusters.append([(axis, run)])
            reach = run["stop"]
    return clusters


def _one_oscillation(cluster: list) -> list[dict] | None:
    """One block when the cluster is one oscillation: a single run, or runs of different axes at one
    frequency each overlapping the first by more than half of the shorter (the axes driven
    together); the first run's extent and cycles. None otherwise."""
    (axis, first), rest = cluster[0], cluster[1:]
    axes = [axis]
    for other_axis, run in rest:
        overlap = min(first["stop"], run["stop"]) - max(first["start"], run["start"])
        if (
            other_axis in axes
            or not _same_frequency(first["frequency_hz"], run["frequency_hz"])
            or overlap <= 0.5 * min(first["stop"] - first["start"], run["stop"] - run["start"])
        ):
            return None
        axes.append(other_axis)
    return [{**first, "kind": "detected", "axes": axes}]


def _stretches(cluster: list, sample_rate_hz: float) -> list[dict]:
    """Non-overlapping blocks of overlapping runs: the stretches between consecutive run edges, each
    of the runs covering it, cut to whole cycles (of the one run's period, aligned to its cycles, or
    of the period at which the runs repeat together; a stretch of runs that do not repeat together
    is kept whole, without a frequency); stretches of fewer than MIN_CYCLES are left out."""
    edges = sorted({edge for _, run in cluster for edge in (run["start"], run["stop"])})
    out = []
    for lo, hi in zip(edges, edges[1:]):
        covering = [(axis, run) for axis, run in cluster if run["start"] <= lo and run["stop"] >= hi]
        if not covering:
            continue
        frequencies = {axis: float(run["frequency_hz"]) for axis, run in covering}
        if len(covering) == 1:  # whole cycles of the run, on its own cycle grid
            run = covering[0][1]
            period = sample_rate_hz / run["frequency_hz"]
            first = int(np.ceil((lo - run["start"]) / period - 1e-6))
            last = int(np.floor((hi - run["start"]) / period + 1e-6))
            block = {
                "start": run["start"] + int(round(first * period)),
                "cycles": last - first,
                "frequency_hz": float(run["frequency_hz"]),
            }
        else:  # whole common cycles, if the stretch holds MIN_CYCLES
            joint = joint_frequency_hz(list(frequencies.values()))
            cycles = int(np.floor((hi - lo) * joint / sample_rate_hz + 1e-6)) if joint else 0
            periodic = cycles >= MIN_CYCLES
            block = {
                "start": int(lo),
                "cycles": cycles if periodic else None,
                "frequency_hz": joint if periodic else None,
                "frequencies_hz": frequencies,
                "joint_frequency_hz": joint,
            }
        if block["frequency_hz"] is None:
            if hi - lo < MIN_CYCLES * sample_rate_hz / min(frequencies.values()):
                continue
            block["stop"] = int(hi)
        elif block["cycles"] < MIN_CYCLES:
            continue
        else:
            block["stop"] = block["start"] + int(round(block["cycles"] * sample_rate_hz / block["frequency_hz"]))
        out.append({**block, "kind": "detected", "axes": [axis for axis, _ in covering]})
    return out


def _same_frequency(a_hz: float, b_hz: float) -> bool:
    return abs(a_hz - b_hz) <= SAME_FREQUENCY_SHARE * max(a_hz, b_hz)


def joint_frequency_hz(frequencies_hz: list[float]) -> float | None:
    """The frequency (Hz) at which drives at ``frequencies_hz`` repeat together: the slowest divided
    by the least common denominator of the others' ratios to it (each p/q with q ≤
    MAX_JOINT_DENOMINATOR, within JOINT_RATIO_SHARE); None if some ratio is not such a fraction."""
    slowest = min(frequencies_hz)
    denominator = 1
    for f in frequencies_hz:
        ratio = f / slowest
        q = next(
            (
                q
                for q in range(1, MAX_JOINT_DENOMINATOR + 1)
                if abs(ratio * q - round(ratio * q)) <= JOINT_RATIO_SHARE * ratio * q
            ),
            None,
        )
        if q is None:
            return None
        denominator = denominator * q // math.gcd(denominator, q)
    return slowest / denominator if denominator <= MAX_JOINT_DENOMINATOR else None


#: why a stretch of an imported record is in no block (it stays in the record: models run through it)
OUTSIDE_BLOCKS = (
    "not steady oscillation (a rest, a ramp, or the first cycle out of a rest, before the "
    "oscillation is steady): outside the blocks"
)


def blocks_without_table(drives_v: dict[str, np.ndarray], sample_rate_hz: float) -> list[dict]:
    """The block table of a record that came without one: its steady stretches when there are several
    (a sweep over frequencies or axes, bursts between holds); else one block over the whole record,
    with the frequency and whole cycles of its one steady oscillation if it has one; and if a rest
    of more than one period comes before or after that oscillation, the block is the oscillation
    alone and ``trimmed`` says how long the rest was (s) before and after it. With several blocks,
    each block's ``trimmed`` gives the stretch between the previous block (or the record's start)
    and it, and the last block's also the stretch after it: what no block holds is reported. A
    step-hold between or around the oscillations is one block per level (service.science.data.steps)."""
    n = len(next(iter(drives_v.values())))
    blocks = _with_steps(detect_blocks(drives_v, sample_rate_hz), drives_v, sample_rate_hz, n)
    if len(blocks) >= 2:
        previous_stop = 0
        for k, block in enumerate(blocks):
            after = n - int(block["stop"]) if k == len(blocks) - 1 else 0
            block["trimmed"] = {
                "before_s": max(0, int(block["start"]) - previous_stop) / sample_rate_hz,
                "after_s": after / sample_rate_hz,
                "why": OUTSIDE_BLOCKS,
            }
            previous_stop = max(previous_stop, int(block["stop"]))
        return blocks
    whole = {
        "index": 0,
        "start": 0,
        "stop": n,
        "kind": "imported",
        "frequency_hz": None,
        "cycles": None,
        "axes": list(drives_v),
    }
    if blocks:
        run = blocks[0]
        together = {k: run[k] for k in ("frequencies_hz", "joint_frequency_hz") if k in run}
        f = run["frequency_hz"]  # None: axes driven at once that do not repeat together
        period = sample_rate_hz / (f or min(run["frequencies_hz"].values()))
        before, after = int(run["start"]), n - int(run["stop"])
        if max(before, after) > period:  # a rest (or a ramp) around the excitation: the block is the
            # steady oscillation alone, so its cycles and held-out cycles are the drive's own; the
            # rest stays in the record (the model runs through it) and is reported
            return [
                {
                    **whole,
                    "start": int(run["start"]),
                    "stop": int(run["stop"]),
                    "frequency_hz": f,
                    "cycles": run["cycles"],
                    "axes": run["axes"],
                    **together,
                    "trimmed": {
                        "before_s": before / sample_rate_hz,
                        "after_s": after / sample_rate_hz,
                        "why": OUTSIDE_BLOCKS,
                    },
                }
            ]
        cycles = int(np.floor(n * f / sample_rate_hz + 1e-9)) if f else None
        whole.update(frequency_hz=f, cycles=cycles, axes=run["axes"], **together)
    return [whole]


def _with_steps(blocks: list[dict], drives_v: dict[str, np.ndarray], sample_rate_hz: float, n: int) -> list[dict]:
    """``blocks`` and the step-holds in the stretches between them (one axis's: the first whose drive
    steps there), in time order, indexed from 0."""
    edges = [0] + [e for b in blocks for e in (int(b["start"]), int(b["stop"]))] + [n]
    still = {axis: held_still(u, sample_rate_hz) for axis, u in drives_v.items()}  # once per drive
    steps = []
    for a, b in zip(edges[::2], edges[1::2]):
        for axis, u in drives_v.items():
            found = step_blocks(u, sample_rate_hz, a, b, [axis], still[axis])
            if found:
                steps.extend(found)
                break
    if not steps:
        return blocks
    merged = sorted(blocks + steps, key=lambda blk: int(blk["start"]))
    return [{**blk, "index": k} for k, blk in enumerate(merged)]
