"""Stages with a disturbance or a slow gain change beside the material (issue 38), built without the
product's code on tests/support/hysteresis_worlds.py's materials and drives.

- ``"hum"``: mains pickup on the gauge, 12 nm at 50 Hz and 4 nm at 150 Hz (phases 0.4 and 1.1 rad),
  running on through blocks and rests (in the one-CSV-per-block form each file starts at its own
  t = 0 and the line's phase with it, as a lab's files would);
- ``"gainfade"``: the stack's gain falls 0.1 % a second (x·(1 − 0.001·t), t from each record's start).

Units: µm for displacements, V for drives, s for time, Hz for frequencies.
"""

from __future__ import annotations

import numpy as np

from tests.support.hysteresis_worlds import SAMPLE_RATE_HZ, WORLDS, blocks_v

#: (frequency Hz, amplitude µm, phase rad) of the hum's lines
HUM_LINES = ((50.0, 0.012, 0.4), (150.0, 0.004, 1.1))
#: the gain's fall, share per second
GAIN_FADE_PER_S = 0.001
KINDS = ("clean", "hum", "gainfade")


def disturbed_um(kind: str, x_um: np.ndarray, fs: float) -> np.ndarray:
    """The gauge's reading (µm, before its noise) of a stage whose output is ``x_um`` with ``kind``."""
    t = np.arange(x_um.size) / fs
    if kind == "clean":
        return x_um
    if kind == "hum":
        return x_um + sum(a * np.sin(2 * np.pi * f * t + p) for f, a, p in HUM_LINES)
    if kind == "gainfade":
        return x_um * (1.0 - GAIN_FADE_PER_S * t)
    raise ValueError(kind)


def pairs(world: str, kind: str, form: str, noise_um: float = 0.002, seed: int = 0, fs: float = SAMPLE_RATE_HZ):
    """[(u_v, x_um)]: one per block ("blocks", each from rest at its own t = 0) or one long record
    ("long": every block one after the other with their rests), the gauge's noise added."""
    rng = np.random.default_rng(seed)
    drives = blocks_v(fs=fs)
    drives = drives if form == "blocks" else [np.concatenate(drives)]
    out = []
    for u in drives:
        x = disturbed_um(kind, WORLDS[world](u, False), fs)
        out.append((u, x + rng.normal(0.0, noise_um, u.size)))
    return out


def records(world: str, kind: str, form: str = "blocks", noise_um: float = 0.002, seed: int = 0, fs=SAMPLE_RATE_HZ):
    """Held-out product Records of the stage, blocks cut by the product's importer as a CSV's are."""
    from service.science.data.segmentation import blocks_without_table
    from service.science.discovery.records import records_from_arrays

    out = []
    for k, (u, x) in enumerate(pairs(world, kind, form, noise_um, seed, fs)):
        table = blocks_without_table({"y": u}, fs)
        out += records_from_arrays({"u_y_v": u, "x_y_um": x}, fs, table, ("y",), f"{world}:{kind}:{form}{k}:")
    return out


def foreign_records(kind: str, form: str = "long", noise_um: float = 0.002, seed: int = 7):
    """The issue's stages on tests/support/foreign_stage.py's Bouc–Wen (5 kHz, ±150 V bursts at
    1/10/50/100 Hz from a 3 s rest with 0.5 s gaps): "long" one record, "blocks" one per burst, each
    from its own 0.5 s rest; ``kind`` as ``disturbed_um``."""
    from service.science.data.segmentation import blocks_without_table
    from service.science.discovery.records import records_from_arrays
    from tests.support import foreign_stage

    fs = foreign_stage.SAMPLE_RATE_HZ
    rng = np.random.default_rng(seed)
    if form == "long":
        drives = [foreign_stage.drive_v()]
    else:
        drives = [
            foreign_stage.drive_v(frequencies_hz=(f,), cycles=(c,), rest_s=0.5, gap_s=0.5)
            for f, c in zip((1, 10, 50, 100), (5, 10, 20, 30))
        ]
    out = []
    for k, u in enumerate(drives):
        x = disturbed_um(kind, foreign_stage.bouc_wen_um(u), fs) + rng.normal(0.0, noise_um, u.size)
        out += records_from_arrays(
            {"u_y_v": u, "x_y_um": x}, fs, blocks_without_table({"y": u}, fs), ("y",), f"foreign:{kind}:{form}{k}:"
        )
    return out
