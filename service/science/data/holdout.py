"""The train/held-out split of a record by whole cycles (service.science.fitting.validation
measures a model on it).

Within each block of a record, the last ⌈20 %⌉ of its full cycles (at least one) are held out and
the earlier full cycles train; a block without cycles (step, non-periodic import) holds out its
last 20 % of samples. Samples outside every block (ramps, settling) and a trailing part-cycle belong
to neither set, though models still run over them so that their operator state carries through the
whole record. A step block (a level held) before the record's drive has first reached an end of its
range belongs to neither set either (``state_known_from``). Pure numpy: sample indices
(start, stop) into a record.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: share of a block's full cycles held out (at least one cycle)
HELD_OUT_FRACTION = 0.2


@dataclass(frozen=True)
class BlockSplit:
    """One block's training and held-out sample ranges (start, stop), in record indices."""

    block: dict
    train: tuple[int, int]
    held_out: tuple[int, int]


def other_axes(block: dict, axis: str | None) -> list[str]:
    """The axes ``block`` drove when ``axis`` is not among them (``axis`` was at rest: its record shows
    cross-coupling there), else [] (a block of ``axis``, or one whose axes are not recorded)."""
    driven = block.get("axes") or []
    return list(driven) if axis and driven and axis not in driven else []


def axis_frequency_hz(block: dict, axis: str | None) -> float | None:
    """The frequency (Hz) at which ``block`` drove ``axis``: its own where the block drove the axes
    at different frequencies (``frequencies_hz``, an imported two-axis record), else the block's."""
    return (block.get("frequencies_hz") or {}).get(axis) or block.get("frequency_hz")


#: how near (a share of the drive's range) the drive must come to an end of its range to set the state
RANGE_END_SHARE = 0.002


def state_known_from(u_v: np.ndarray) -> int:
    """The first sample (index) from which a rate-independent stage's state no longer depends on what
    came before the record: the drive's first visit to the top or the bottom of its range after it has
    left its starting level. A record starts wherever the stage was left (a file cut from a session
    starts at the last block's remnant displacement, with its memory); a play operator is set again
    when the drive reaches an end of the range its history stayed within. 0 for a drive that never
    moves."""
    u = np.asarray(u_v, dtype=float)
    if u.size == 0:
        return 0
    lo, hi = float(np.min(u)), float(np.max(u))
    tolerance = RANGE_END_SHARE * (hi - lo)
    moved = np.flatnonzero(np.abs(u - u[0]) > tolerance)
    if moved.size == 0:
        return 0
    first = int(moved[0])
    at_end = np.flatnonzero((u[first:] >= hi - tolerance) | (u[first:] <= lo + tolerance))
    return first + int(at_end[0]) if at_end.size else 0


def split_blocks(
    blocks: Sequence[dict],
    samples: int,
    sample_rate_hz: float,
    axis: str | None = None,
    fraction: float = HELD_OUT_FRACTION,
    known_from: int = 0,
) -> list[BlockSplit]:
    """Train/held-out ranges per block. Blocks that drive other axes only are skipped when
    ``axis`` is given; an empty block table means one block over the whole record. With
    ``fraction`` 0 nothing is held out: a block's whole cycles (or all its samples) train.

    Before ``known_from`` (``state_known_from``) the stage's state is what the record does not show: a
    step block (a level held) that ends before it is left out and one that straddles it trains from
    there, and a periodic block trains from there if it comes within its first cycle. A record starts
    wherever the session left the stage; fitted to a fresh stage's state, its first steps bent the
    whole model (a Maxwell-slip stage cut one file per block: 2.83 nm held out against a 2.02 nm floor
    with them, 2.03 nm without). An imported block of another drive keeps its start (a random drive
    may reach its top only halfway), and so does every block where nothing would be left.
    """
    if not blocks:
        blocks = [{"index": 0, "start": 0, "stop": samples, "kind": "imported", "frequency_hz": None, "cycles": None}]
    out = [split for block in blocks if (split := _split(block, samples, sample_rate_hz, axis, fraction, known_from))]
    if known_from and not out:
        return split_blocks(blocks, samples, sample_rate_hz, axis, fraction)
    return out


def _split(block: dict, samples: int, sample_rate_hz: float, axis, fraction: float, known_from: int):
    """One block's split (``split_blocks``), or None when it has none."""
    if other_axes(block, axis):
        return None
    start, stop = int(block["start"]), min(int(block["stop"]), samples)
    if stop - start < 2:
        return None
    f_hz, cycles = block.get("frequency_hz"), block.get("cycles")
    period = sample_rate_hz / float(f_hz) if f_hz else 0.0
    full = min(int(cycles), int(math.floor((stop - start) / period + 1e-9))) if period and cycles and cycles >= 1 else 0
    if full >= 1:
        held = max(1, math.ceil(fraction * full - 1e-9)) if fraction > 0 else 0
        cut = start + int(round((full - held) * period))
        end = min(stop, start + int(round(full * period)))
        first = max(start, known_from) if known_from < min(start + period, cut) else start
        return BlockSplit(block, (first, cut), (cut, end))
    if block.get("kind") == "step":
        start = max(start, known_from)
    if stop - start < 2:
        return None
    cut = stop - (max(1, math.ceil(fraction * (stop - start))) if fraction > 0 else 0)
    return BlockSplit(block, (start, cut), (cut, stop))


def training_mask(splits: Sequence[BlockSplit], samples: int) -> np.ndarray:
    """Boolean mask of the training rows of one record."""
    mask = np.zeros(samples, dtype=bool)
    for s in splits:
        mask[s.train[0] : s.train[1]] = True
    return mask
