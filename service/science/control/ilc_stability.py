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
class LearningPrediction:
    """Predicted per-period convergence factor of the ILC on one axis (< 1: the learnable error falls
    by at least this factor per period at every harmonic, for any gain in the band), the harmonic
    (0..K) where it is worst, and the largest learning gain γ that keeps it below ``LIMIT`` (0 when
    no γ converges: the ratio's phase passes 90° somewhere)."""

    axis: str
    factor: float
    worst_harmonic: int
    gain: float
    max_gain: float

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
    plant: AxisPlant, pid: tuple | None, frequency_hz: float, harmonics: int, share: float = MINOR_LOOP_SHARE
) -> np.ndarray:
    """G/Ĝ (harmonics+1, BAND_POINTS²): the closed loop at each plant gain of the band over the one
    at each other, per harmonic 0..K of ``frequency_hz``."""
    f = frequency_hz * np.arange(harmonics + 1)
    gains = plant.gain_um_per_v * np.linspace(share, 1.0, BAND_POINTS)
    t = np.stack(
        [
            closed_loop_um_per_v(AxisPlant(g, plant.resonance_hz, plant.damping_ratio, plant.delay_s), pid, f)
            for g in gains
        ],
        axis=1,
    )  # (K+1, band)
    return (t[:, :, None] / t[:, None, :]).reshape(len(f), -1)


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


def predict_learning(
    axis: str,
    plant: AxisPlant | None,
    pid: tuple | None,
    gain: float,
    frequency_hz: float,
    harmonics: int,
    latency_periods: int = 0,
    share: float = MINOR_LOOP_SHARE,
) -> LearningPrediction:
    """``LearningPrediction`` of learning gain ``gain`` on harmonics 0..``harmonics`` of ``frequency_hz``
    around ``plant`` under ``pid`` (see the module doc), corrections applied ``latency_periods`` late.
    Without a PID the plant may be None (the band's ratios are then share..1/share at every harmonic)."""
    if pid is None:
        r = np.array([share, 1.0 / share])[None, :].repeat(harmonics + 1, axis=0).astype(complex)
    elif plant is None:
        raise ValueError("a PID's closed loop needs the axis's plant")
    else:
        r = gain_ratios(plant, pid, frequency_hz, harmonics, share)
    per_k = np.max(factors(gain, r, latency_periods), axis=1)
    k = int(np.argmax(per_k))
    return LearningPrediction(axis, float(per_k[k]), k, float(gain), max_learning_gain(r, latency_periods))


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
    plants: dict, gains: dict | None, gain: float, frequency_hz: float, harmonics: int, latency_periods: int = 0
) -> list[LearningPrediction]:
    """One ``LearningPrediction`` per axis of ``plants`` (axis → AxisPlant or None) under ``gains``
    (axis → (kp, ki, kd, tf_s), or None without PID). ValueError when a PID axis has no plant."""
    out = []
    for axis, plant in plants.items():
        pid = None if gains is None else gains.get(axis)
        if pid is not None and plant is None:
            raise ValueError(
                f"the {axis.upper()} learning cannot be predicted under a PID without the axis's plant "
                f"(give controller.feedforward_model_{axis})"
            )
        out.append(predict_learning(axis, plant, pid, gain, frequency_hz, harmonics, latency_periods))
    return out


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
