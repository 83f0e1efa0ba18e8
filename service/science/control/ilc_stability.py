"""Will the learning converge? The harmonic ILC's convergence factor predicted before a run.

The ILC (service.science.control.ilc) learns U_{j+1}(k) = U_j(k) + γ·E_j(k)/Ĝ(k), so the error at
harmonic k of the trajectory frequency evolves as E_{j+1}(k) = (1 − γ·G(k)/Ĝ(k))·E_j(k), where G(k)
(µm/V) is what the learning input actually sees: the closed loop from the feedforward input to the
gauge, T = P/(1 + C·P) with the chosen PID C (T = P without PID), P the axis's plant with its flexure
mode and loop delay (service.science.control.stability). Ĝ is measured on the bench at one amplitude
and refined from the run, but the piezo's incremental gain depends on the amplitude: a small minor
loop has about a third of the full swing's (≈ 0.03 against ≈ 0.08 µm/V on the default bench). So G
and Ĝ are the closed loop around any plant gain in [MINOR_LOOP_SHARE·g, g] (g: the largest slope),
and the predicted factor is the worst |1 − γ·T(k; g₁)/T(k; g₂)| over that band and harmonics 0..K.
Without a PID the ratio is a positive real number and the factor does not depend on the plant.
With a PID that leaves thin margins, T's peak moves with the gain and the ratio's phase passes 90°:
no learning gain converges then.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from service.science.control.stability import AxisPlant, controller_response, plant_response

#: incremental gain of a small minor loop as a share of the full swing's (≈ 0.03 / 0.08 µm/V, issue 19)
MINOR_LOOP_SHARE = 0.35
#: plant gains sampled across the band [MINOR_LOOP_SHARE·g, g]
BAND_POINTS = 9


@dataclass(frozen=True)
class ModeSpread:
    """The identified mode's uncertainty: the range of its frequency (Hz) and damping ratio over the
    identifications at hand (the feedforward model's, the bench's declared mode, the plant's assumed
    damping), widened to at least ±FN_SPREAD_FLOOR and ×/÷ ZETA_SPREAD_FLOOR."""

    fn_hz: tuple[float, float]
    zeta: tuple[float, float]

    def plants(self, plant: AxisPlant) -> list[AxisPlant]:
        """``plant`` with its mode at each corner and the centre of the spread."""
        fns = (self.fn_hz[0], float(np.sqrt(self.fn_hz[0] * self.fn_hz[1])), self.fn_hz[1])
        zetas = (self.zeta[0], float(np.sqrt(self.zeta[0] * self.zeta[1])), self.zeta[1])
        return [AxisPlant(plant.gain_um_per_v, fn, z, plant.delay_s) for fn in fns for z in zetas]


#: the least uncertainty granted an identified mode: ±3 % in frequency, ×/÷ 1.5 in damping (sweeps up
#: to 100 Hz see a 290–480 Hz mode only through its gain's rise, tuning.plant_from_model)
FN_SPREAD_FLOOR = 0.03
ZETA_SPREAD_FLOOR = 1.5


def mode_spread(fns_hz, zetas) -> ModeSpread | None:
    """``ModeSpread`` of the finite identified frequencies ``fns_hz`` (Hz) and damping ratios ``zetas``
    (None without a finite frequency)."""
    fns = [float(f) for f in fns_hz if f is not None and np.isfinite(f)]
    zs = [float(z) for z in zetas if z is not None and np.isfinite(z) and z > 0]
    if not fns or not zs:
        return None
    lo, hi = min(fns), max(fns)
    centre = np.sqrt(lo * hi)
    lo, hi = min(lo, centre * (1 - FN_SPREAD_FLOOR)), max(hi, centre * (1 + FN_SPREAD_FLOOR))
    zc = np.sqrt(min(zs) * max(zs))
    return ModeSpread((lo, hi), (min(min(zs), zc / ZETA_SPREAD_FLOOR), max(max(zs), zc * ZETA_SPREAD_FLOOR)))


@dataclass(frozen=True)
class LearningPrediction:
    """Predicted per-period convergence factor of the ILC on one axis (< 1: the learnable error falls
    by at least this factor per period at every learned harmonic, for any gain in the band and any
    mode in the spread), the harmonic (0..K) where it is worst, the largest learning gain γ that keeps
    it below ``LIMIT`` (0 when no γ converges: the ratio's phase passes 90° somewhere); ``expected``:
    the median factor at the fundamental over the band and spread (what a run's error decay per period
    should show, ``measured_factor``); ``harmonics``: the harmonics 0..K the robustness filter lets
    learn (up to ``evidence_harmonics``), ``cut_hz`` the first one it cuts."""

    axis: str
    factor: float
    worst_harmonic: int
    gain: float
    max_gain: float
    expected: float = float("nan")
    harmonics: int = -1
    cut_hz: float | None = None

    def as_dict(self) -> dict:
        return asdict(self)


#: a factor at or above this is predicted to diverge (the error grows at some harmonic for some gain
#: in the band)
LIMIT = 1.0


def closed_loop_um_per_v(plant: AxisPlant, pid: tuple | None, f_hz: np.ndarray) -> np.ndarray:
    """T(j2πf) (µm/V) from the feedforward input to the gauge: P/(1 + C·P) with ``pid`` (kp V/µm,
    ki V/(µm·s), kd V·s/µm, tf_s s[, mode damping section]), or P without one. DC (f = 0) is taken at 1e-3 Hz."""
    f = np.maximum(np.asarray(f_hz, dtype=float), 1e-3)
    p = plant_response(plant, f)
    if pid is None:
        return p
    return p / (1.0 + controller_response(pid, f) * p)


def gain_ratios(
    plant: AxisPlant,
    pid: tuple | None,
    frequency_hz: float,
    harmonics: int,
    share: float = MINOR_LOOP_SHARE,
    spread: ModeSpread | None = None,
) -> np.ndarray:
    """G/Ĝ (harmonics+1, BAND_POINTS² × modes): the closed loop at each plant gain of the band over
    the one at each other, per harmonic 0..K of ``frequency_hz``, on ``plant``'s mode or on each mode
    of ``spread`` (Ĝ is measured on the same stage as G: one mode per ratio, wherever it is)."""
    f = frequency_hz * np.arange(harmonics + 1)
    gains = plant.gain_um_per_v * np.linspace(share, 1.0, BAND_POINTS)
    out = []
    for mode in [plant] if spread is None else spread.plants(plant):
        t = np.stack(
            [
                closed_loop_um_per_v(AxisPlant(g, mode.resonance_hz, mode.damping_ratio, mode.delay_s), pid, f)
                for g in gains
            ],
            axis=1,
        )  # (K+1, band)
        out.append((t[:, :, None] / t[:, None, :]).reshape(len(f), -1))
    return np.concatenate(out, axis=1)


def factors(gain: float, ratios: np.ndarray, latency_periods: int = 0) -> np.ndarray:
    """Per-period convergence factor for each ratio r = G/Ĝ: the largest root modulus of
    z^(d+1) − z^d + γ·r = 0, d = ``latency_periods`` (0: a correction learned from period j is applied
    in period j+1, |1 − γr|; 1: in period j+2, buffered streaming). Only d ∈ {0, 1} is needed."""
    a = gain * ratios
    if latency_periods == 0:
        return np.abs(1.0 - a)
    if latency_periods != 1:
        raise ValueError("latency_periods: 0 or 1")
    root = np.sqrt(1.0 - 4.0 * a + 0j)
    return np.maximum(np.abs(0.5 * (1 + root)), np.abs(0.5 * (1 - root)))


#: the robustness filter's corner over the top of the mode's spread: above it the identification (sweeps up
#: to 100 Hz, the harmonics of their loops) holds no evidence of the plant, the learning filter's inverse
#: gain grows as f², and learning there made the 200 Hz ellipse diverge on the default bench (K = 20:
#: 0.85–33 % relative error from run to run; K = 5: 0.27 %, the error at the gauge noise)
Q_OVER_MODE = 2.0


def evidence_harmonics(spread: ModeSpread, frequency_hz: float) -> int:
    """The harmonics of ``frequency_hz`` up to Q_OVER_MODE × the top of the mode's ``spread`` (at least 1)."""
    return max(1, int(np.floor(Q_OVER_MODE * spread.fn_hz[1] / frequency_hz)))


def predict_learning(
    axis: str,
    plant: AxisPlant | None,
    pid: tuple | None,
    gain: float,
    frequency_hz: float,
    harmonics: int,
    latency_periods: int = 0,
    share: float = MINOR_LOOP_SHARE,
    spread: ModeSpread | None = None,
) -> LearningPrediction:
    """``LearningPrediction`` of learning gain ``gain`` on harmonics 0..``harmonics`` of ``frequency_hz``
    around ``plant`` under ``pid`` (see the module doc), corrections applied ``latency_periods`` late,
    over the mode's ``spread`` when given (then the robustness filter keeps the harmonics up to
    ``evidence_harmonics``; the factor is judged over those).
    Without a PID the plant may be None (the band's ratios are then share..1/share at every harmonic)."""
    if pid is None:
        r = np.array([share, 1.0 / share])[None, :].repeat(harmonics + 1, axis=0).astype(complex)
    elif plant is None:
        raise ValueError("a PID's closed loop needs the axis's plant")
    else:
        r = gain_ratios(plant, pid, frequency_hz, harmonics, share, spread)
    all_f = factors(gain, r, latency_periods)
    per_k = np.max(all_f, axis=1)
    kept = harmonics if spread is None else min(harmonics, evidence_harmonics(spread, frequency_hz))
    k = int(np.argmax(per_k[: kept + 1]))
    return LearningPrediction(
        axis,
        float(per_k[k]),
        k,
        float(gain),
        max_learning_gain(r[: kept + 1], latency_periods),
        expected=float(np.median(all_f[min(1, harmonics)])),
        harmonics=kept,
        cut_hz=None if kept == harmonics else float(frequency_hz * (kept + 1)),
    )


#: learning gains scanned for the largest one that converges
GAIN_GRID = np.logspace(-3, np.log10(2.0), 300)


def max_learning_gain(ratios: np.ndarray, latency_periods: int = 0, limit: float = LIMIT) -> float:
    """The largest γ on GAIN_GRID below which every ratio's factor stays under ``limit`` (0 if even
    the smallest fails: some r has Re r ≤ 0, the learning turns the error the wrong way)."""
    ok = np.array([np.max(factors(g, ratios, latency_periods)) < limit for g in GAIN_GRID])
    if not ok[0]:
        return 0.0
    return float(GAIN_GRID[np.argmin(ok) - 1] if not ok.all() else GAIN_GRID[-1])


def learning_refusal(predictions: list[LearningPrediction]) -> tuple[str, str] | None:
    """(field, reason) when any axis's learning is predicted to diverge, else None: the field is
    ``controller.ilc_gain`` when a smaller gain would converge, ``controller.ilc`` when none would."""
    bad = [p for p in predictions if p.factor >= LIMIT]
    if not bad:
        return None
    parts = [
        f"{p.axis.upper()}: predicted convergence factor {p.factor:.2f} per period at harmonic "
        f"{p.worst_harmonic} (≥ {LIMIT:g}: diverges)"
        for p in bad
    ]
    if all(p.max_gain > 0 for p in bad):
        top = min(p.max_gain for p in bad)
        return "controller.ilc_gain", (
            f"ILC learning gain {bad[0].gain:g} is predicted to diverge: "
            + "; ".join(parts)
            + f". A learning gain ≤ {np.floor(top * 100) / 100:.2f} converges on this plant "
            "and PID over the amplitude band"
        )
    return "controller.ilc", (
        "ILC learning is predicted to diverge at any learning gain with this PID: "
        + "; ".join(parts)
        + ". The closed loop's response moves by more than 90° between the "
        'small-signal and full-swing gain of the piezo (thin PID margins); use "pid": "auto" '
        "or no PID under ILC"
    )


def predict_plan(
    plants: dict,
    gains: dict | None,
    gain: float,
    frequency_hz: float,
    harmonics: int,
    latency_periods: int = 0,
    spreads: dict | None = None,
) -> list[LearningPrediction]:
    """One ``LearningPrediction`` per axis of ``plants`` (axis → AxisPlant or None) under ``gains``
    (axis → (kp, ki, kd, tf_s), or None without PID), over each axis's mode spread of ``spreads``
    (axis → ModeSpread or None). ValueError when a PID axis has no plant."""
    out = []
    for axis, plant in plants.items():
        pid = None if gains is None else gains.get(axis)
        if pid is not None and plant is None:
            raise ValueError(
                f"the {axis.upper()} learning cannot be predicted under a PID without the axis's plant "
                f"(give controller.feedforward_model_{axis})"
            )
        spread = (spreads or {}).get(axis)
        out.append(predict_learning(axis, plant, pid, gain, frequency_hz, harmonics, latency_periods, spread=spread))
    return out


def trajectory_gain_um_per_v(model, u_drive_v: np.ndarray, steady: slice, fs: float) -> float:
    """The identified ``model``'s gain (µm/V) along the planned drive ``u_drive_v`` over its ``steady``
    samples: the slope of its stack (before the mode and the delay) against the drive, least squares."""
    u = np.asarray(u_drive_v, dtype=float)
    stack = np.asarray(model.stack_demand_um(model.predict(u, sample_rate_hz=fs), fs), dtype=float)[steady]
    e = u[steady] - np.mean(u[steady])
    return float(np.dot(e, stack - stack.mean()) / max(float(np.dot(e, e)), 1e-30))


def prior_scale(
    g0: np.ndarray, frequency_hz: float, pid: tuple | None, trajectory_gain: float, mode: tuple | None
) -> float:
    """κ: the stack's gain along the trajectory (``trajectory_gain`` µm/V, ``trajectory_gain_um_per_v``)
    over its gain under the response measurement's small probe, read off the measured G₀ (K+1,) at the
    fundamental of ``frequency_hz``: the plant P = T/(1 − C·T) under ``pid``, less the identified
    ``mode``'s (Hz, ζ) gain. The probe's small minor loops see a third to a half of the trajectory's
    gain (MINOR_LOOP_SHARE; measured on the default bench at 100 Hz: G₀ 0.031 µm/V on Y, the run's
    refined Ĝ 0.065): the learning's prior is scaled by κ (``scaled_response``). Within
    [1, 1/MINOR_LOOP_SHARE]: a probe never sees more gain than the trajectory."""
    f = np.array([float(frequency_hz)])
    t = complex(g0[1])
    p = t if pid is None else t / (1.0 - complex(controller_response(tuple(pid), f)[0]) * t)
    m = 1.0 if mode is None else float(np.abs(plant_response(AxisPlant(1.0, mode[0], mode[1], 0.0), f))[0])
    small = abs(p) / m
    if not (small > 0 and trajectory_gain > 0):
        return 1.0
    return float(np.clip(trajectory_gain / small, 1.0, 1.0 / MINOR_LOOP_SHARE))


def scaled_response(g: np.ndarray, frequency_hz: float, pid: tuple | None, kappa: float) -> np.ndarray:
    """G₀ (K+1,) µm/V, the closed loop from the feedforward input to the gauge measured at harmonics
    0..K of ``frequency_hz``, with the plant inside it scaled by ``kappa``: P = T/(1 − C·T),
    T_κ = κP/(1 + κC·P) under ``pid`` (T_κ = κT without one); G(0) as |G(1)| (ilc.frf_from_periods)."""
    t = np.asarray(g[1:], dtype=complex)
    if pid is None:
        out = kappa * t
    else:
        c = controller_response(tuple(pid), frequency_hz * np.arange(1, g.size))
        p = t / (1.0 - c * t)
        out = kappa * p / (1.0 + kappa * c * p)
    return np.concatenate([[abs(out[0])], out]).astype(complex)


#: a run's error decay is read while the error per period is above this multiple of its floor (the
#: median of its last FLOOR_PERIODS periods): below it the noise and unlearnable harmonics dominate
DECAY_ABOVE_FLOOR = 3.0
FLOOR_PERIODS = 10


def measured_factor(error_per_period_um) -> float | None:
    """The convergence factor a run showed: the geometric mean per-period ratio of its error (RMS per
    period) from its second learning period while it stays above DECAY_ABOVE_FLOOR × its floor; None
    when fewer than two periods are above it (nothing to learn, or too short a run). The first step is
    left out: it learns through G₀, measured with a 4 V multisine whose minor loops have a smaller gain
    than the trajectory's; from the second on, Ĝ is refined from the run itself (service.science.control.ilc)."""
    e = np.asarray(error_per_period_um, dtype=float)
    if e.size < FLOOR_PERIODS + 3:
        return None
    floor = float(np.median(e[-FLOOR_PERIODS:]))
    below = np.flatnonzero(e <= DECAY_ABOVE_FLOOR * floor)
    last = int(below[0]) - 1 if below.size else e.size - 1
    if last < 2:
        return None
    return float((e[last] / e[1]) ** (1.0 / (last - 1)))


def learning_diagnosis(ilc, report: dict | None) -> str:
    """Why a run with ILC tripped, in words: how the error per period went while ``ilc`` (a
    HarmonicILC) learned, its reverts, and the predicted factors of ``report`` (``{"axes": {axis:
    LearningPrediction.as_dict()}}``, None when not predicted)."""
    h = np.asarray(ilc.history_um) * 1e3
    if len(h) == 0:
        said = "the ILC had not learned yet (tripped before the first steady period)"
    else:
        trend = "rising" if len(h) > 1 and h[-1] > 1.5 * np.min(h) else "not rising"
        said = (
            f"the ILC had learned for {len(h)} periods, error {h[0]:.1f} → {h[-1]:.1f} nm RMS per period "
            f"(best {np.min(h):.1f}, {trend}; {ilc.reverts} reverts{': ' + ilc.stop_reason if ilc.stop_reason else ''})"
        )
    if report:
        said += (
            "; predicted convergence factor "
            + ", ".join(f"{a.upper()} {p['factor']:.2f}" for a, p in report["axes"].items())
            + f" (≥ {LIMIT:g} diverges)"
        )
    else:
        said += "; its convergence was not predicted"
    return said
