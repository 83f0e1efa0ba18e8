"""docs/calibration.md's account of the Table 6 fit: the parameters with their bounds and sources,
the targets met or not, and the physical floors that keep the 100 Hz cells above the paper's.
The search itself is service/reports/calibration_fit.py."""

from __future__ import annotations

import math

from drivers.emulated.config import load_config
from service.reports.calibration import PAPER
from service.reports.calibration_fit import (
    CELL_TOLERANCE,
    PARAMETERS,
    PI_1HZ_MARGIN,
    WEIGHT_100HZ,
    measure_axis,
    target_checks,
)
from service.reports.reproduction import PAPER_TABLE6_UM

#: Parameters the fit does not move, and where their values come from.
FIXED = (
    ("flexure.resonance_hz", "first modes from the paper's FEM (Fig. 1d,e); a target, not a fitted value"),
    (
        "piezo.reversible_um_per_v",
        "scaled with the switched strain, electrostriction and saturation by one "
        "factor per evaluation, so that the 1 Hz stroke is the paper's",
    ),
    ("piezo.hysteresis.switched_um", "idem (the Preisach density's shape, coercive mode and bias are unchanged)"),
    ("amplifier.bandwidth.bandwidth_hz", "PZD350-class channel into 1.8 µF (not fitted)"),
)


#: The Y values ``--fit`` found (stroke-scaled), NOT in default.toml: with them the default-bench
#: discovery test (tests/unit/science/test_discovery_default.py) adds rate_dependence first, whose fit then takes the
#: flexure's lag, and never claims dynamics. Y keeps its former values; the notes measure this set.
Y_FIT_NOT_LANDED = {
    "piezo.rate_dependence.relaxation_s": 4.444e-3,
    "piezo.rate_dependence.relaxing_fraction": 0.1419,
    "piezo.asymmetry.saturation_um": 6.426,
    "piezo.asymmetry.electrostrictive_um_per_v2": 2.2022e-5,
    "piezo.creep.rate_per_decade": 0.01309,
    "flexure.dynamics.damping_ratio": 0.2114,
    "gauge.bandwidth.bandwidth_hz": 54230.0,
    "piezo.reversible_um_per_v": 0.02019,
    "piezo.hysteresis.switched_um": 4.502,
}


def y_fit_rows(bench: str = "default") -> list[str]:
    """Markdown: the Y set ``Y_FIT_NOT_LANDED`` measured now (the reproduction's sweep and fits), target by target."""
    measured = measure_axis("y", Y_FIT_NOT_LANDED, bench)
    rows = [
        "| parameter | value |",
        "|---|---|",
        *(f"| `{k}` | {v:.4g} |" for k, v in Y_FIT_NOT_LANDED.items()),
        "",
        "| target (Y fit, not landed) | figures | met |",
        "|---|---|---|",
    ]
    rows += [
        f"| {name} | {figures} | {'✓' if met else '✗'} |"
        for name, met, figures in target_checks("y", measured["rms_um"], measured["stroke_um"])
    ]
    rows.append(
        f"| static PI at 1 Hz (calibration test: within 2× of 0.0881) | "
        f"{measured['rms_um']['static']['1 Hz']:.4f} µm | — |"
    )
    return rows


def _config_value(cfg: dict, axis: str, key: str) -> float:
    node = cfg["axes"][axis]
    for part in key.split("."):
        node = node.get(part, 1.0) if isinstance(node, dict) else node
    return float(node)


def parameter_table(bench: str = "default") -> list[str]:
    """Markdown rows: every fitted and every stroke-scaled parameter with its Y and Z values,
    bound and source."""
    cfg = load_config(bench)
    rows = ["| parameter (`axes.<axis>.…`) | Y | Z | bound | source or inference |", "|---|---|---|---|---|"]
    for p in PARAMETERS:
        y, z = (_config_value(cfg, axis, p.key) for axis in ("y", "z"))
        rows.append(
            f"| `{p.key}` | {y:.4g} | {z:.4g} | {p.low:g}–{p.high:g} | Z fitted, Y its former value "
            f"(below); bound: {p.why} |"
        )
    for key, why in FIXED:
        y, z = (_config_value(cfg, axis, key) for axis in ("y", "z"))
        rows.append(f"| `{key}` | {y:.4g} | {z:.4g} | — | {why} |")
    return rows


def flexure_floor_um(axis: str, bench: str = "default", frequency_hz: float = 100.0) -> dict[str, float]:
    """What the flexure alone costs a 1 Hz-fitted static PI at ``frequency_hz``, for ANY damping: a
    second-order mode at f_n passes the drive's fundamental with |H − 1| ≥ r²/(1 − r²), r = f/f_n
    (the minimum is at ζ → 0 for r < 1/√2), on the fundamental's amplitude (half the paper's stroke).
    Also the AO→AI latency's phase at ``frequency_hz`` and what it alone costs."""
    cfg = load_config(bench)
    r = frequency_hz / float(cfg["axes"][axis]["flexure"]["resonance_hz"])
    amplitude_um = PAPER[axis]["stroke_um"] / 2.0
    gain_excess = r * r / (1.0 - r * r)
    latency_s = (
        cfg["daq"]["latency"]["samples"] / cfg["daq"]["sample_rate_hz"] if cfg["daq"]["latency"]["enabled"] else 0.0
    )
    phase_rad = 2 * math.pi * frequency_hz * latency_s
    return {
        "r": r,
        "gain_excess": gain_excess,
        "flexure_rms_um": gain_excess * amplitude_um / math.sqrt(2.0),
        "latency_rad": phase_rad,
        "latency_rms_um": phase_rad * amplitude_um / math.sqrt(2.0),
    }


def fit_markdown(rms_by_axis: dict, z_stroke_100hz_um: float, bench: str = "default") -> str:
    """docs/calibration.md's account of the fit: the parameters with their sources, every target
    of Table 6 met or not on ``rms_by_axis`` ({axis: identify_axis(...)["rms_um"]}), and why the
    unmet ones stay unmet (the flexure's and the latency's floors computed from the config).
    ``z_stroke_100hz_um``: the emulated Z stroke at 100 Hz, 0–120 V (last cycle)."""
    lines = _method_lines(bench)
    for axis in ("y", "z"):
        for name, met, figures in target_checks(axis, rms_by_axis[axis]):
            lines.append(f"| {name} | {figures} | {'✓' if met else '✗'} |")
    lines += _y_fit_lines(bench)
    lines += _disagreement_lines(z_stroke_100hz_um, bench)
    return "\n".join(lines) + "\n"


def _method_lines(bench: str) -> list[str]:
    """How the fit works, its parameters, and the head of the Table 6 targets' table."""
    return [
        "## Fitted parameters",
        "",
        "Fitted by `python -m service.reports.calibration --fit` (module `service/reports/calibration_fit.py`): "
        "per axis, a bounded Nelder–Mead over the parameters below, each mapped to [0, 1] inside its bound "
        "(log-mapped where the bound spans a decade), from the bench's previous values. One evaluation sweeps "
        "the axis at 1, 10, 50 and 100 Hz exactly as `python -m service.reports.reproduction` does, after "
        "scaling the stack's strain coefficients so that the 1 Hz stroke is the paper's, and fits the static "
        "PI, GRPI and dynamic PI (exact least squares). The objective sums, per axis: each 10 Hz cell's log "
        "ratio to the paper's in units of log 1.35 and the dynamic PI's 10 Hz reduction of the static PI's "
        "error in units of 15 points (steep beyond the target, gentle inside it); the 100 Hz cells' squared "
        f"log ratios at weight {WEIGHT_100HZ:g} (their floor, below, is physical); hinges on the paper's "
        "ordering; and the calibration test's 1 Hz guards with a margin (loop width 10.5–14.5 %, static PI "
        f"at 1 Hz within {PI_1HZ_MARGIN:g}× of the paper's; the test allows 10–15 % and 2×). The search's own figures: "
        "`--log FILE` keeps every evaluation.",
        "",
        *parameter_table(bench),
        "",
        "## Table 6 targets on the calibrated bench",
        "",
        "From the reproduction's own sweep (seed 0). ✓ met, ✗ not met.",
        "",
        "| target | figures | met |",
        "|---|---|---|",
    ]


def _y_fit_lines(bench: str) -> list[str]:
    """The Y set the fit found, and why it is not the default."""
    return [
        "",
        "## The Y set the fit found, and why it is not the default",
        "",
        "`--fit` on Y (same objective) found the set below: every 10 Hz cell within ±35 % and the paper's "
        "ordering, the 10 Hz reduction just short of the 26 % it needs, the 100 Hz cells out of reach as on "
        "Z. It is not in default.toml: with it, `tests/unit/science/test_discovery_default.py` fails — discovery on the "
        "default bench's Y record adds rate_dependence first (the millisecond relaxation is now the largest "
        "effect), its fit takes the flexure's lag with it, and dynamics is never claimed (the test requires "
        "asymmetry, dynamics and cross_coupling among the effects added). The discovery thresholds were not "
        "touched; Y keeps its former values until that is resolved. (This set was found while the "
        "damping's upper bound was still 0.3: its ζ of 0.21 would also fail the emulator's resonance test.)",
        "",
        *y_fit_rows(bench),
        "",
    ]


def _disagreement_lines(z_stroke_100hz_um: float, bench: str) -> list[str]:
    """The residual disagreements with Table 6 and the floors (flexure, latency) behind them."""
    floors = {axis: flexure_floor_um(axis, bench) for axis in ("y", "z")}
    ceiling = {axis: PAPER_TABLE6_UM[axis][100.0][2] * (1 + CELL_TOLERANCE) for axis in ("y", "z")}
    fy, fz = floors["y"], floors["z"]
    z_pp_um, z_stroke = 11.0 - 1.0, PAPER["z"]["stroke_um"]
    #: the fundamental's relative gain excess the Z ceiling leaves room for, over the paper's 1 Hz floor
    allowed = math.sqrt(max(ceiling["z"] ** 2 - PAPER["z"]["pi_rms_1hz_um"] ** 2, 0.0)) * math.sqrt(2) / (z_stroke / 2)
    return [
        "",
        "## Residual disagreements, and why",
        "",
        f"- **The 100 Hz cells have a physical floor.** A second-order mode at f_n passes a drive at f with "
        f"|H − 1| ≥ r²/(1 − r²), r = f/f_n, whatever its damping (the bound is reached as ζ → 0; more damping "
        f"adds phase lag, less lets the loop's harmonics ring the mode). At 100 Hz that is "
        f"{100 * fy['gain_excess']:.1f} % on Y (r = {fy['r']:.3f}) and {100 * fz['gain_excess']:.1f} % on Z "
        f"(r = {fz['r']:.3f}) of the fundamental, i.e. at least {fy['flexure_rms_um']:.3f} µm and "
        f"{fz['flexure_rms_um']:.3f} µm rms that a static PI fitted at 1 Hz cannot follow, against the paper's "
        f"static-PI figures {PAPER_TABLE6_UM['y'][100.0][2]:.4f} and {PAPER_TABLE6_UM['z'][100.0][2]:.4f} µm "
        f"(±35 % ceilings {ceiling['y']:.3f} and {ceiling['z']:.3f}). The DAQ's one-sample AO→AI latency adds "
        f"{1e3 * fy['latency_rad']:.1f} mrad of lag at 100 Hz ({fy['latency_rms_um']:.3f} µm on Y, "
        f"{fz['latency_rms_um']:.3f} µm on Z). So on Z no damping meets the 100 Hz static-PI cell with the "
        f"FEM's 290.7 Hz mode in the path. More damping lowers the 100 Hz ringing (Z's third harmonic sits on "
        f"the mode) but adds lag, and above ζ = 0.1 the mode stops being a resonance (its peak falls below 4× "
        f"the low-frequency gain and more than 2 % below f_n), so Z's ζ sits at that bound. The paper's 100 Hz "
        f"figures imply a first mode well above the FEM's, or a static PI refitted at 100 Hz: for the "
        f"fundamental alone to stay within the Z ceiling, r²/(1 − r²) ≤ {allowed:.3f}, i.e. f_n ≥ "
        f"{100.0 / math.sqrt(_r2_for_excess(allowed)):.0f} Hz (given the paper's own 1 Hz floor of "
        f"{PAPER['z']['pi_rms_1hz_um']:.4f} µm).",
        f"- **The paper's own Z numbers pull apart.** Case 1 tracks Z over 1–11 µm ({z_pp_um:g} µm peak to peak) "
        f"at 100 Hz, {z_pp_um / z_stroke:.3f}× the 1 Hz stroke of {z_stroke:.2f} µm at 0–120 V. Either the "
        f"100 Hz loop is ≥ {100 * (z_pp_um / z_stroke - 1):.1f} % larger than the 1 Hz loop at 0–120 V — and "
        f"then a 1 Hz static PI leaves ≥ {(z_pp_um / z_stroke - 1) * z_stroke / 2 / math.sqrt(2):.3f} µm rms at "
        f"100 Hz, not Table 6's {PAPER_TABLE6_UM['z'][100.0][2]:.4f} µm — or the tracking drove the stack past "
        f"120 V (to ≈ {120 * z_pp_um / z_stroke:.0f} V at the 1 Hz gain), outside the range Table 6 was identified on. "
        f"The emulator keeps the FEM mode: its Z stroke at 100 Hz and 0–120 V is {z_stroke_100hz_um:.2f} µm "
        f"({z_stroke_100hz_um / z_stroke:.3f}× the 1 Hz stroke), so case 1 "
        + ("fits inside 0–120 V" if z_stroke_100hz_um >= z_pp_um else "needs more than 120 V")
        + ", and its Table 6 Z 100 Hz cells stay above the paper's.",
        "- **The paper's material data bound the damping and the relaxation.** Table 1 gives the stack's "
        "mechanical quality factor Q_m = 45 (ζ = 1/(2 Q_m) ≈ 0.011 for the ceramic alone, so the flexure's ζ "
        "is not below 0.02 with bolted joints added) and a small-signal dielectric loss tan δ = 1.5 %. The "
        "fitted relaxation is a large-signal domain-wall effect on the switched strain, not bounded by tan δ; "
        "its phase peak at 1/(2πτ) is what lets the dynamic PI, whose weights move with u̇ and ü, beat the "
        "static PI at 10 Hz.",
    ]


def _r2_for_excess(excess: float) -> float:
    """r² such that r²/(1 − r²) = ``excess``."""
    return excess / (1.0 + excess)
