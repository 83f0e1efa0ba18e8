"""Loop-stability arithmetic for a PID (paper eq. 19: e in µm, u in V, t in s) around one flexure
axis modelled as a static gain times its first mode: G(s) = g·ωn²/(s² + 2ζωn·s + ωn²).

``delay_margin`` answers "how much loop delay can these gains stand?": the crossover frequency of
C(s)·G(s) and the pure delay that would use up its phase margin. A sampled loop has at least one
sample of latency plus half a sample of hold (75 µs at 20 kHz); a USB DAQ in a software loop, ~1 ms.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DelayMargin:
    crossover_hz: float       #: highest frequency where |C·G| = 1
    phase_margin_deg: float   #: at that crossover, without delay
    delay_margin_s: float     #: the pure delay that brings the phase margin to 0


def delay_margin(kp: float, ki: float, kd: float, gain_um_per_v: float, resonance_hz: float,
                 damping_ratio: float, f_max_hz: float = 1e6) -> DelayMargin:
    """Crossover, phase margin and delay margin of PID (kp V/µm, ki V/(µm·s), kd V·s/µm) on the
    second-order axis above (gain µm/V, first mode in Hz, damping ratio). Unfiltered derivative."""
    w = 2 * np.pi * np.logspace(0, np.log10(f_max_hz), 200_000)
    s = 1j * w
    wn = 2 * np.pi * resonance_hz
    loop = (kp + ki / s + kd * s) * gain_um_per_v * wn ** 2 / (s ** 2 + 2 * damping_ratio * wn * s + wn ** 2)
    above = np.abs(loop) >= 1.0
    if not above.any():
        return DelayMargin(float("nan"), float("inf"), float("inf"))
    i = int(np.flatnonzero(above)[-1])
    pm = 180.0 + float(np.degrees(np.angle(loop[i])))
    return DelayMargin(float(w[i] / (2 * np.pi)), pm, float(np.radians(pm) / w[i]))
