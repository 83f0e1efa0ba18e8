"""Damping a flexure mode in the tracking loop: positive position feedback (PPF), run on the error.

Why: the feedforward inverts the identified model, and what the model gets wrong at the harmonic of
the ellipse next to an axis's flexure mode reaches the gauge multiplied by the mode's peak
(docs/tracking_error_spectrum.md: 1/(2ζ), 5× to 25×). A PID cannot reach it: with 6 dB gain margin on a
lightly damped mode its crossover stays at a few hertz. PPF (Goh and Caughey 1985; Fleming and
Leang, *Design, Modeling and Control of Nanopositioning Systems*, 2014, ch. 8) adds damping at the
mode with a low-pass section tuned to it, and rolls off above it.

Here the section acts on the tracking error e = r − x (µm), in parallel with the PID:
R(s) = −k·ωf²/(s² + 2ζf·ωf·s + ωf²) (V/µm). The loop it closes is that of PPF on x; the reference
path differs by the term R·r only, so when the tracking is perfect the section is silent and the
feedforward, identified in open loop, stays valid. The compiled loop runs it as a biquad
(``biquad``: bilinear transform with the section's frequency pre-warped).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

#: the highest section frequency, as a share of the loop's sample rate, at which the compiled
#: biquad still has the designed response (2 % at 0.05, 6 % at 0.1: tests/unit/science/test_control_damping.py);
#: a mode above it is left undamped (a trajectory far below it hardly excites it)
MAX_FREQUENCY_SHARE = 0.1


def realisable(frequency_hz: float, sample_rate_hz: float) -> bool:
    """Whether a section at ``frequency_hz`` runs as designed in a loop at ``sample_rate_hz``."""
    return 0.0 < frequency_hz <= MAX_FREQUENCY_SHARE * sample_rate_hz


@dataclass(frozen=True)
class ModeDamping:
    """One PPF section on the error: DC gain ``gain_v_per_um`` (V/µm, k above), tuned to
    ``frequency_hz`` with damping ratio ``damping_ratio``."""

    gain_v_per_um: float
    frequency_hz: float
    damping_ratio: float

    def response(self, f_hz: np.ndarray) -> np.ndarray:
        """R(j2πf) (V/µm)."""
        s = 2j * np.pi * np.asarray(f_hz, dtype=float)
        w = 2 * np.pi * self.frequency_hz
        return -self.gain_v_per_um * w**2 / (s**2 + 2 * self.damping_ratio * w * s + w**2)

    def biquad(self, sample_rate_hz: float) -> tuple[float, float, float, float, float]:
        """(b0, b1, b2, a1, a2) of the section at ``sample_rate_hz`` (a0 = 1): bilinear transform,
        pre-warped so that the digital section peaks at ``frequency_hz``. ValueError at or above the
        Nyquist frequency."""
        if not 0.0 < self.frequency_hz < sample_rate_hz / 2:
            raise ValueError(f"a damping section at {self.frequency_hz:g} Hz cannot run at {sample_rate_hz:g} Hz")
        w = 2 * np.pi * self.frequency_hz
        c = w / np.tan(w / (2 * sample_rate_hz))  # pre-warped s = c·(z − 1)/(z + 1)
        z = self.damping_ratio
        a0 = c * c + 2 * z * w * c + w * w
        k = -self.gain_v_per_um * w * w / a0
        return (k, 2 * k, k, 2 * (w * w - c * c) / a0, (c * c - 2 * z * w * c + w * w) / a0)

    def as_dict(self) -> dict:
        return asdict(self)
