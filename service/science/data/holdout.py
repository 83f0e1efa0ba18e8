"""The train/held-out split of a record by whole cycles (service.science.fitting.validation
measures a model on it).

Within each block of a record, the last ⌈20 %⌉ of its full cycles (at least one) are held out and
the earlier full cycles train; a block without cycles (step, non-periodic import) holds out its
last 20 % of samples. Samples outside every block (ramps, settling) and a trailing part-cycle belong
to neither set, though models still run over them so that their operator state carries through the
whole record. Pure numpy: sample indices (start, stop) into a record.
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


def split_blocks(
    blocks: Sequence[dict],
    samples: int,
    sample_rate_hz: float,
    axis: str | None = None,
    fraction: float = HELD_OUT_FRACTION,
) -> list[BlockSplit]:
    """Train/held-out ranges per block. Blocks that drive other axes only are skipped when
    ``axis`` is given; an empty block table means one block over the whole record. With
    ``fraction`` 0 nothing is held out: a block's whole cycles (or all its samples) train."""
    if not blocks:
        blocks = [{"index": 0, "start": 0, "stop": samples, "kind": "imported", "frequency_hz": None, "cycles": None}]
    out = []
    for block in blocks:
        if other_axes(block, axis):
            continue
        start, stop = int(block["start"]), min(int(block["stop"]), samples)
        if stop - start < 2:
            continue
        f_hz, cycles = block.get("frequency_hz"), block.get("cycles")
        if f_hz and cycles and cycles >= 1:
            period = sample_rate_hz / float(f_hz)
            full = min(int(cycles), int(math.floor((stop - start) / period + 1e-9)))
        else:
            full = 0
        if full >= 1:
            held = max(1, math.ceil(fraction * full - 1e-9)) if fraction > 0 else 0
            cut = start + int(round((full - held) * period))
            end = min(stop, start + int(round(full * period)))
            out.append(BlockSplit(block, (start, cut), (cut, end)))
        else:
            cut = stop - (max(1, math.ceil(fraction * (stop - start))) if fraction > 0 else 0)
            out.append(BlockSplit(block, (start, cut), (cut, stop)))
    return out


def training_mask(splits: Sequence[BlockSplit], samples: int) -> np.ndarray:
    """Boolean mask of the training rows of one record."""
    mask = np.zeros(samples, dtype=bool)
    for s in splits:
        mask[s.train[0] : s.train[1]] = True
    return mask
