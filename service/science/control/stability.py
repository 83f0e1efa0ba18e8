"""Loop-stability arithmetic for a PID (paper eq. 19: e in µm, u in V, t in s) around one flexure
axis modelled as a static gain times its first mode and a pure delay:
G(s) = g·ωn²/(s² + 2ζωn·s + ωn²)·e^(−sτ).

``loop_margins`` predicts what a gain set leaves: every gain crossover's phase margin, the gain
margin at every phase crossover, the delay margin (the extra pure delay that brings the worst
crossover's phase margin to 0) and closed-loop stability itself (Nyquist: the winding of 1 + L).
A sampled loop has at least one sample of latency plus half a sample of hold (75 µs at 20 kHz),
plus the DAQ's own pipeline (``loop_delay_s``); a USB DAQ in a software loop, ~1 ms.
``delay_margin`` is the older question without delay or derivative filter (kept for the notes).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

#: the frequency grid (Hz) margins are read on: 0.01 Hz … 200 kHz, fine enough to resolve a mode
#: with ζ = 0.01 (its half-power width is 2ζ·fn)
GRID_HZ = np.logspace(-2, np.log10(2e5), 12_000)


@dataclass(frozen=True)
class AxisPlant:
    """One axis as the loop sees it: static gain µm/V (the largest incremental slope, for safety),
    first flexure mode (Hz, damping ratio) and the loop's pure delay (s); ``resonance_of``: where the
    mode's frequency comes from, in words."""

    gain_um_per_v: float
    resonance_hz: float
    damping_ratio: float
    delay_s: float
    resonance_of: str = "the bench's declared first resonance"

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class LoopMargins:
    """What a PID leaves on an ``AxisPlant``: ``stable`` (the closed loop, delay included),
    the lowest phase margin (deg: the angle from L to −1 at a gain crossover, whichever way round)
    over the gain crossovers and the crossover it is at (Hz), the
    lowest gain margin (dB) over the phase crossovers, the delay margin (s) and the loop delay (s)
    it was computed with. ``inf`` where there is no crossover."""

    stable: bool
    crossover_hz: float
    phase_margin_deg: float
    gain_margin_db: float
    delay_margin_s: float
    loop_delay_s: float

    def as_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in asdict(self).items()}


def loop_delay_s(sample_rate_hz: float, latency_samples: int = 0) -> float:
    """The pure delay (s) of a per-sample loop: one sample (the command uses the previous sample's
    measurement), half a sample of hold, and the DAQ's pipeline of ``latency_samples``."""
    return (1.5 + latency_samples) / sample_rate_hz


def pid_response(kp: float, ki: float, kd: float, tf_s: float, f_hz: np.ndarray) -> np.ndarray:
    """C(jω) (V/µm) of the PID as the compiled loop runs it: kp + ki/s + kd·s/(1 + tf·s)."""
    s = 2j * np.pi * np.asarray(f_hz, dtype=float)
    return kp + ki / s + kd * s / (1.0 + tf_s * s)


def controller_response(gains: tuple, f_hz: np.ndarray) -> np.ndarray:
    """C(j2πf) (V/µm) of ``gains`` = (kp, ki, kd, tf_s) or (kp, ki, kd, tf_s, damping), damping a
    ``ModeDamping`` section (service.science.control.damping) or None: the PID plus the section, as
    the compiled loop runs them in parallel on the error."""
    c = pid_response(*gains[:4], f_hz)
    damping = gains[4] if len(gains) > 4 else None
    return c if damping is None else c + damping.response(f_hz)


def plant_response(plant: AxisPlant, f_hz: np.ndarray) -> np.ndarray:
    """G(jω) (µm/V) of ``plant`` (without a mode when its resonance is not finite)."""
    s = 2j * np.pi * np.asarray(f_hz, dtype=float)
    if not np.isfinite(plant.resonance_hz):  # no mode declared or identified: gain and delay
        return plant.gain_um_per_v * np.exp(-s * plant.delay_s)
    wn = 2 * np.pi * plant.resonance_hz
    mode = wn**2 / (s**2 + 2 * plant.damping_ratio * wn * s + wn**2)
    return plant.gain_um_per_v * mode * np.exp(-s * plant.delay_s)


def margins_of(loop: np.ndarray, f_hz: np.ndarray, delay_s: float) -> LoopMargins:
    """``LoopMargins`` of the open loop ``loop`` = L(j2πf) sampled on ``f_hz`` (rising, from well below
    the lowest crossover to where |L| ≪ 1).

    Stability by Nyquist for an open loop with no right-half-plane pole: along ω = 0+ … ∞ the phase of
    1 + L must rise by exactly +90° with an integrator (from −90° to 0°), by 0° without one; each
    encirclement of −1 takes 360° off."""
    mag = np.abs(loop)
    turn = np.angle(1.0 + loop)  # the phase of 1 + L, then its steps
    steps = np.diff(turn)  # wrapped to (−π, π]: the angle of each
    steps -= 2 * np.pi * np.round(steps / (2 * np.pi))  # step's ratio (1 + L[k+1])/(1 + L[k])
    wind = turn[0] + np.sum(steps)
    stable = abs(wind) < np.pi / 2
    cross = np.flatnonzero(np.diff(np.sign(mag - 1.0)) != 0)
    if len(cross):
        phase_deg = np.degrees(np.angle(loop[cross]))  # (−180°, 180°]: a derivative's lead counts
        pm_i = 180.0 - np.abs(phase_deg)  # the angle to −1 either way round
        lag_room_rad = np.radians(np.mod(phase_deg + 180.0, 360.0))  # a delay only turns the phase back
        w_i = 2 * np.pi * f_hz[cross]
        worst = int(np.argmin(pm_i))
        pm, fc = float(pm_i[worst]), float(f_hz[cross[worst]])
        dm = float(np.min(lag_room_rad / w_i))
    else:
        pm, fc, dm = float("inf"), float("nan"), float("inf")
    # phase crossovers: L crosses the negative real axis (its imaginary part changes sign where its
    # real part is negative)
    neg = np.flatnonzero((np.diff(np.sign(loop.imag)) != 0) & (loop.real[:-1] < 0))
    gm = float(np.min(-20 * np.log10(np.maximum(mag[neg], 1e-300)))) if len(neg) else float("inf")
    return LoopMargins(bool(stable), fc, pm, gm, dm, float(delay_s))


def loop_margins(
    kp: float, ki: float, kd: float, tf_s: float, plant: AxisPlant, f_hz: np.ndarray = GRID_HZ, damping=None
) -> LoopMargins:
    """Predicted ``LoopMargins`` of PID (kp V/µm, ki V/(µm·s), kd V·s/µm, derivative filter tf_s s),
    with the mode ``damping`` section in parallel when given, on ``plant``."""
    loop = controller_response((kp, ki, kd, tf_s, damping), f_hz) * plant_response(plant, f_hz)
    return margins_of(loop, f_hz, plant.delay_s)


@dataclass(frozen=True)
class DelayMargin:
    crossover_hz: float  #: highest frequency where |C·G| = 1
    phase_margin_deg: float  #: at that crossover, without delay
    delay_margin_s: float  #: the pure delay that brings the phase margin to 0


def delay_margin(
    kp: float,
    ki: float,
    kd: float,
    gain_um_per_v: float,
    resonance_hz: float,
    damping_ratio: float,
    f_max_hz: float = 1e6,
) -> DelayMargin:
    """Crossover, phase margin and delay margin of PID (kp V/µm, ki V/(µm·s), kd V·s/µm) on the
    second-order axis above (gain µm/V, first mode in Hz, damping ratio). Unfiltered derivative."""
    w = 2 * np.pi * np.logspace(0, np.log10(f_max_hz), 200_000)
    s = 1j * w
    wn = 2 * np.pi * resonance_hz
    loop = (kp + ki / s + kd * s) * gain_um_per_v * wn**2 / (s**2 + 2 * damping_ratio * wn * s + wn**2)
    above = np.abs(loop) >= 1.0
    if not above.any():
        return DelayMargin(float("nan"), float("inf"), float("inf"))
    i = int(np.flatnonzero(above)[-1])
    pm = 180.0 + float(np.degrees(np.angle(loop[i])))
    return DelayMargin(float(w[i] / (2 * np.pi)), pm, float(np.radians(pm) / w[i]))
