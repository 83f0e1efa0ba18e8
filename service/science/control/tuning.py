"""Gains the service chooses: a PID per axis tuned on the plant identified on the bench, and the
margins any gain set leaves on it (a request's gains are chosen and judged by
service.science.control.gains).

The plant (``plant_from_model``): the largest incremental slope of the identified feedforward
model's rising branch (µm/V: for a PI, its weight sum, reached once every operator moves), the
flexure's first mode (the bench's declared resonance, with the lighter of the model's identified
damping ratio and ``ASSUMED_DAMPING``) and the loop's delay
(``stability.loop_delay_s``). The largest slope is the safe choice: a smaller incremental gain
(after a reversal) lowers the loop gain, which these loops tolerate (``MIN_GAIN_MARGIN_DB``).

``tune`` minimises the tracking error left at the trajectory's frequency and its first harmonics
(the sensitivity |1/(1 + L)|), keeping the largest integral gain (against creep and drift) the
rest allows, subject to ``Targets``: phase margin, gain margin and delay margin (a multiple of the
loop's own delay), with the derivative filter fixed (``TF_S``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from service.science.control.damping import ModeDamping, realisable
from service.science.control.loop import PIDGains
from service.science.control.session import SAMPLE_RATE_HZ
from service.science.control.stability import (
    GRID_HZ,
    AxisPlant,
    LoopMargins,
    loop_delay_s,
    loop_margins,
    margins_of,
    pid_response,
    plant_response,
)
from service.science.discovery.composite import as_composite

#: damping ratio assumed for a flexure mode no model has identified (lighter than typical: a safe guess)
ASSUMED_DAMPING = 0.02
#: derivative filter time constant (s) of tuned gains: a 0.8 kHz corner, below the 10 kHz Nyquist limit
TF_S = 2e-4
#: voltage (V) over which a model's rising branch is read for its largest slope (the paper's range)
SLOPE_SPAN_V = 120.0


@dataclass(frozen=True)
class Targets:
    """What a gain set must leave: phase margin (deg), gain margin (dB), delay margin as a multiple
    of the loop's delay."""

    phase_margin_deg: float = 60.0
    gain_margin_db: float = 6.0
    delay_margin_factor: float = 3.0

    def failures(self, m: LoopMargins) -> list[str]:
        """The margins ``m`` misses, in words (empty when it meets every target)."""
        out = []
        if not m.stable:
            out.append("closed loop unstable")
        if not m.phase_margin_deg >= self.phase_margin_deg:
            out.append(f"phase margin {m.phase_margin_deg:.1f}° < {self.phase_margin_deg:g}°")
        if not m.gain_margin_db >= self.gain_margin_db:
            out.append(f"gain margin {m.gain_margin_db:.1f} dB < {self.gain_margin_db:g} dB")
        need_s = self.delay_margin_factor * m.loop_delay_s
        if not m.delay_margin_s >= need_s:
            out.append(
                f"delay margin {m.delay_margin_s * 1e6:.0f} µs < {self.delay_margin_factor:g} × the loop's "
                f"{m.loop_delay_s * 1e6:.0f} µs delay"
            )
        return out

    def as_dict(self) -> dict:
        return {
            "phase_margin_deg": self.phase_margin_deg,
            "gain_margin_db": self.gain_margin_db,
            "delay_margin_factor": self.delay_margin_factor,
        }


def largest_slope_um_per_v(model, sample_rate_hz: float, span_v: float = SLOPE_SPAN_V) -> float:
    """The largest incremental gain (µm/V) along the model's quasi-static rising branch 0 → ``span_v``
    (0.5 s raised-cosine ramp), read over 1 V steps."""
    n = int(sample_rate_hz / 2)
    u = 0.5 * span_v * (1 - np.cos(np.pi * np.arange(n) / n))
    x = np.asarray(model.predict(u, sample_rate_hz=sample_rate_hz), dtype=float)
    grid_v = np.arange(0.0, span_v * 0.999, 1.0)
    x_grid = np.interp(grid_v, u, x)
    return float(np.max(np.diff(x_grid)))


def identified_mode(model) -> tuple[float, float] | None:
    """(resonance Hz, damping ratio) of the model's identified flexure dynamics, or None."""
    try:
        theta = as_composite(model).theta
    except (AttributeError, NotImplementedError, ValueError):
        return None
    dyn = theta.get("dynamics") if isinstance(theta, dict) else None
    if not dyn or "fn_hz" not in dyn:
        return None
    return float(dyn["fn_hz"]), float(dyn["zeta"])


def plant_from_model(model, resonance_hz: float, delay_s: float, sample_rate_hz: float) -> AxisPlant:
    """The ``AxisPlant`` of one axis from its identified model (see the module doc). The mode is the
    bench's first resonance ``resonance_hz`` (the model's identified one where the bench declares
    none). Sweeps up to 100 Hz cannot pin the damping of a 290–480 Hz mode (seen identified at 0.005
    and at 0.17 on the same bench, whose true ratio is 0.04–0.05; tuning on 0.17 tripped the loop),
    so the damping is the lighter of the identified one and ``ASSUMED_DAMPING``."""
    mode = identified_mode(model)
    declared = np.isfinite(resonance_hz) or mode is None
    fn_hz = resonance_hz if declared else mode[0]
    zeta = ASSUMED_DAMPING if mode is None else min(mode[1], ASSUMED_DAMPING)
    of = "the bench's declared first resonance" if declared else "the feedforward model's identified mode"
    return AxisPlant(largest_slope_um_per_v(model, sample_rate_hz), fn_hz, zeta, delay_s, of)


@dataclass(frozen=True)
class Tuned:
    """Gains (kp V/µm, ki V/(µm·s), kd V·s/µm, tf_s s), the mode damping section run beside them
    (None: none) and the margins they leave on the plant."""

    kp: float
    ki: float
    kd: float
    tf_s: float
    margins: LoopMargins
    damping: ModeDamping | None = None

    def gains(self) -> PIDGains:
        """The gains and damping section, as ``choose_pid`` (service.science.control.gains) and the loop take them."""
        return PIDGains(self.kp, self.ki, self.kd, self.tf_s, self.damping)


def _best_ki(
    plant: AxisPlant,
    targets: Targets,
    kp: float,
    kd: float,
    ki_grid: np.ndarray,
    f_hz: np.ndarray,
    responses: list[np.ndarray],
    extra: np.ndarray | float = 0.0,
) -> float:
    """The largest ki on ``ki_grid`` (rising) for which (kp, ki, kd) beside the response ``extra``
    (V/µm on ``f_hz``: a damping section) meets ``targets`` on every plant response of ``responses``
    (``checked_plants``); 0 if none."""
    c0 = pid_response(kp, 0.0, kd, TF_S, f_hz) + extra
    loops = [(c0 * g, g / (2j * np.pi * f_hz)) for g in responses]
    best = 0.0
    for ki in ki_grid:
        if any(targets.failures(margins_of(base + ki * integ, f_hz, plant.delay_s)) for base, integ in loops):
            break
        best = float(ki)
    return best


def checked_plants(plant: AxisPlant) -> list[AxisPlant]:
    """The plants a gain set must meet the targets on: ``plant`` and the same axis without its mode
    (gain and delay). A stage whose mode is higher than declared, or a bench without flexure dynamics,
    gives the controller's high-frequency gain no roll-off to hide behind: a derivative or a section
    tuned on the declared mode alone can then ring the loop into the amplifier's current limit."""
    return [plant, AxisPlant(plant.gain_um_per_v, float("inf"), plant.damping_ratio, plant.delay_s)]


def worst_failures(targets: Targets, gains: tuple, plant: AxisPlant) -> list[str]:
    """The targets ``gains`` miss on any of ``checked_plants(plant)`` (the mode-less plant's named)."""
    out = []
    for checked in checked_plants(plant):
        margins = loop_margins(*gains[:4], checked, damping=gains[4] if len(gains) > 4 else None)
        said = targets.failures(margins)
        out += said if checked is plant else [f"{f} without the flexure mode" for f in said]
    return out


#: the paper's trajectory frequency (Hz): "tuned" and a tuning without a stated frequency aim there
DESIGN_FREQUENCY_HZ = 100.0
#: the tuning weighs the harmonics of the trajectory frequency up to this multiple of the mode's
#: frequency (the feedforward's error there is what the mode multiplies)
DESIGN_BAND_OVER_MODE = 1.25
#: ... and at most this many harmonics (a mode far above the trajectory)
MAX_DESIGN_HARMONICS = 40
#: the search meets the targets by this much more (phase margin deg, gain margin dB, delay margin
#: factor) on its coarser grid, so that the answer meets them on the fine one
SEARCH_SLACK = (1.0, 0.3, 1.05)
#: PPF sections tried on each axis's mode (service.science.control.damping): the loop's share k·g
#: at DC (PPF alone is stable below 1), the section's damping ratio and its frequency over the mode's
#: (Fleming and Leang 2014, ch. 8: a section a little above the mode, damped 0.2–0.5)
DAMPING_SHARES = (0.1, 0.2, 0.3)
DAMPING_RATIOS = (0.2, 0.3, 0.5)
DAMPING_DETUNES = (1.1, 1.2, 1.4)
#: plant gains the expected error is averaged over, as shares of the largest slope: the tracking
#: runs minor loops whose incremental gain is down to about a third of it (ilc_stability)
GAIN_BAND = (0.35, 0.6, 1.0)
#: damping ratios of the mode the expected error is averaged over: sweeps up to 100 Hz cannot pin it
#: (plant_from_model); the margins are still judged on the lightest (the plant's)
DAMPING_BAND = (0.02, 0.05, 0.1)


def design_harmonics(plant: AxisPlant, frequency_hz: float) -> np.ndarray:
    """The harmonics (Hz) of ``frequency_hz`` the tuning weighs: up to DESIGN_BAND_OVER_MODE × the
    plant's mode, at least the fundamental."""
    top = DESIGN_BAND_OVER_MODE * plant.resonance_hz / frequency_hz
    top = int(min(top, MAX_DESIGN_HARMONICS)) if np.isfinite(top) else 1
    return frequency_hz * np.arange(1, max(1, top) + 1)


def expected_error(plant: AxisPlant, controller: np.ndarray, band_hz: np.ndarray) -> float:
    """The tracking error a controller leaves, relative (1 = the feedforward's own with no
    feedback): the RMS over the plant gains of GAIN_BAND, the mode damping ratios of DAMPING_BAND and
    the harmonics ``band_hz`` of |S·M/k|, S = 1/(1 + C·G) the sensitivity, M the mode's gain (the
    feedforward model's error passes through it) and 1/k the fall of that error with the harmonic's
    order k (docs/tracking_error_spectrum.md). ``controller`` is C on ``band_hz`` (V/µm)."""
    k = np.arange(1, len(band_hz) + 1)
    cost = reference = 0.0
    for zeta in DAMPING_BAND:
        mode = plant_response(AxisPlant(1.0, plant.resonance_hz, zeta, plant.delay_s), band_hz)
        reference += len(GAIN_BAND) * float(np.mean(np.abs(mode / k) ** 2))
        for share in GAIN_BAND:
            g = share * plant.gain_um_per_v * mode
            cost += float(np.mean(np.abs(mode / (k * (1.0 + controller * g))) ** 2))
    return float(np.sqrt(cost / reference))


def damping_candidates(plant: AxisPlant, sample_rate_hz: float = SAMPLE_RATE_HZ) -> list[ModeDamping | None]:
    """None and every PPF section of the grid above on ``plant``'s mode that a loop at
    ``sample_rate_hz`` runs as designed (damping.realisable; none for a mode it cannot see)."""
    return [None] + [
        ModeDamping(share / plant.gain_um_per_v, detune * plant.resonance_hz, ratio)
        for share in DAMPING_SHARES
        for ratio in DAMPING_RATIOS
        for detune in DAMPING_DETUNES
        if np.isfinite(plant.resonance_hz) and realisable(detune * plant.resonance_hz, sample_rate_hz)
    ]


@functools.lru_cache(maxsize=64)  # a pure function of frozen inputs; a search takes seconds
def tune(
    plant: AxisPlant,
    targets: Targets = Targets(),
    frequency_hz: float = DESIGN_FREQUENCY_HZ,
    damp: bool = False,
    sample_rate_hz: float = SAMPLE_RATE_HZ,
) -> Tuned:
    """The PID meeting ``targets`` on ``plant`` that tracks a trajectory at ``frequency_hz`` best, with
    the largest ki (integral action against creep and drift) that kp, kd leave.

    Without ``damp``: best = the lowest sensitivity |1/(1 + L)| at the fundamental. With ``damp``: a
    PPF section on the mode beside the PID, and best = the least ``expected_error`` over the
    harmonics up to the mode; first the section (``_pick_section``), then the PID beside it
    (``_search_pid``). ValueError when no gain set meets the targets."""
    f_hz = GRID_HZ[::3]  # the search reads a coarser grid; the answer is checked on the fine one
    strict = Targets(
        targets.phase_margin_deg + SEARCH_SLACK[0],
        targets.gain_margin_db + SEARCH_SLACK[1],
        targets.delay_margin_factor * SEARCH_SLACK[2],
    )
    band_hz = design_harmonics(plant, frequency_hz) if damp else np.array([float(frequency_hz)])

    def cost_of(c_band: np.ndarray) -> float:
        if damp:
            return expected_error(plant, c_band, band_hz)
        return float(np.max(np.abs(1.0 / (1.0 + c_band * plant_response(plant, band_hz)))))

    damping = _pick_section(plant, strict, f_hz, band_hz, cost_of, sample_rate_hz) if damp else None
    kp, ki, kd = _search_pid(plant, targets, strict, f_hz, band_hz, cost_of, damping)
    for _ in range(40):  # the fine grid may see a sliver the coarse one did not: back off
        misses = worst_failures(targets, (kp, ki, kd, TF_S, damping), plant)
        if not misses:
            return Tuned(kp, ki, kd, TF_S, loop_margins(kp, ki, kd, TF_S, plant, damping=damping), damping)
        kp, ki, kd = 0.95 * kp, 0.95 * ki, 0.95 * kd
    raise ValueError(f"the tuned gains miss the targets on the fine grid: {', '.join(misses)}")


def _ki_grid(plant: AxisPlant) -> np.ndarray:
    return np.logspace(0, 5, 41) / plant.gain_um_per_v


def _pick_section(
    plant: AxisPlant, strict: Targets, f_hz: np.ndarray, band_hz: np.ndarray, cost_of, sample_rate_hz: float
) -> ModeDamping | None:
    """The candidate section (or None) that, beside the largest integral gain it allows within
    ``strict``, leaves the least ``cost_of`` its controller on ``band_hz``."""
    responses = [plant_response(p, f_hz) for p in checked_plants(plant)]
    best, best_cost = None, np.inf
    for candidate in damping_candidates(plant, sample_rate_hz):
        extra = 0.0 if candidate is None else candidate.response(f_hz)
        ki = _best_ki(plant, strict, 0.0, 0.0, _ki_grid(plant), f_hz, responses, extra)
        if ki == 0.0:
            continue
        c_band = ki / (2j * np.pi * band_hz) + (0.0 if candidate is None else candidate.response(band_hz))
        cost = cost_of(c_band)
        if cost < best_cost - 1e-9:
            best, best_cost = candidate, cost
    return best


def _search_pid(
    plant: AxisPlant,
    targets: Targets,
    strict: Targets,
    f_hz: np.ndarray,
    band_hz: np.ndarray,
    cost_of,
    damping: ModeDamping | None,
) -> tuple[float, float, float]:
    """(kp, ki, kd) beside ``damping`` with the least ``cost_of``: a coarse grid over kp and kd (ki by
    a rising scan to the largest that meets ``strict``), then a finer grid around the best."""
    responses = [plant_response(p, f_hz) for p in checked_plants(plant)]
    extra, extra_band = (0.0, 0.0) if damping is None else (damping.response(f_hz), damping.response(band_hz))
    scale = 1.0 / plant.gain_um_per_v  # gains in units of the plant's inverse gain
    best, best_cost = (0.0, 0.0, 0.0), np.inf
    kp_grid = scale * np.logspace(-3, 1, 17)
    kd_grid = scale * np.concatenate(([0.0], np.logspace(-6, -3, 13)))
    ki_grid = _ki_grid(plant)
    for _ in range(2):
        for kp in kp_grid:
            for kd in kd_grid:
                ki = _best_ki(plant, strict, kp, kd, ki_grid, f_hz, responses, extra)
                if ki == 0.0:
                    continue
                cost = cost_of(pid_response(kp, ki, kd, TF_S, band_hz) + extra_band)
                if cost < best_cost - 1e-9:
                    best, best_cost = (float(kp), ki, float(kd)), cost
        kp0, ki0, kd0 = best
        if ki0 == 0.0:
            raise ValueError(
                "no PID meets the targets on this plant: " + ", ".join(f"{k} {v}" for k, v in targets.as_dict().items())
            )
        kp_grid = kp0 * np.logspace(-0.25, 0.25, 9)
        kd_grid = np.concatenate(([0.0], kd0 * np.logspace(-0.25, 0.25, 9))) if kd0 > 0 else kd_grid[:4]
        ki_grid = ki0 * np.logspace(-0.3, 0.3, 41)
    return best


#: "auto" on the default bench (seed 0), plant from the static PI identified on its 1 Hz 0–120 V loop
#: (service.science.control.feedforward.identify; no flexure dynamics, so no damping section);
#: tests/api/test_control_gains.py recomputes it
TUNED_PID = {"y": (0.6095, 252.6, 0.0, TF_S), "z": (0.4188, 121.5, 3.627e-4, TF_S)}
#: PID presets a request may name besides "auto" and explicit gains
PRESETS = ("auto", "tuned", "paper")


#: an identified mode within this share of the plant's (declared) one is the same mode
MODE_AGREEMENT = 0.25


def feedforward_inverts_mode(model, resonance_hz: float) -> bool:
    """Whether ``model`` carries the flexure mode the loop sees at ``resonance_hz`` (its identified
    dynamics within MODE_AGREEMENT of it), so that its inverse already shapes the drive around the
    mode. Its error then sits at the harmonic the mode multiplies, which a PPF section damps. A model
    without that mode leaves its error at the fundamental (the dynamics it lacks), where PPF's
    low-frequency positive feedback would add to it; one whose dynamics sit far from the declared
    mode (a stage without flexure dynamics fits a spurious kilohertz one) gives the section nothing
    to damp (docs/tracking_error_spectrum.md)."""
    mode = identified_mode(model)
    if mode is None:
        return False
    return not np.isfinite(resonance_hz) or abs(mode[0] / resonance_hz - 1.0) <= MODE_AGREEMENT


def bench_plants(bench, models: dict, sample_rate_hz: float) -> dict:
    """axis → ``AxisPlant`` from the axis's feedforward model (None without one), the bench's first
    resonance and the loop delay of a per-sample loop on its DAQ at ``sample_rate_hz``."""
    delay = loop_delay_s(sample_rate_hz, getattr(bench.parts.daq.capabilities, "latency_samples", 0))
    return {
        axis: (
            None
            if models.get(axis) is None
            else plant_from_model(models[axis], bench.limits[axis].first_resonance_hz, delay, sample_rate_hz)
        )
        for axis in bench.axes
    }
