"""Fit the default bench's physical parameters to the paper's Table 6 by a documented search.

``python -m service.reports.calibration --fit [--axis y|z] [--evaluations N] [--log FILE]`` runs it.

What is fitted, per axis (the axes are swept one at a time with the other at 0 V, as the paper did,
so they are independent): the physical parameters of ``PARAMETERS``, each inside a bound stated
beside it. What is matched: the paper's Table 6 at 10 and 100 Hz (dynamic PI, GRPI, static PI), the
dynamic PI's reduction of the static PI's error at 10 Hz, and the paper's ordering dynamic < GRPI ≤
static where the paper has it. The 1 Hz stroke is held to the paper's by construction: before each
evaluation every strain coefficient of the stack (reversible, switched, electrostrictive,
saturation) is multiplied by one factor, which scales the strain exactly (tanh(cs/(c·S))·c·S = c·…),
so the stroke lands on the paper's 6.4 / 9.3 µm whatever the other parameters are.

One evaluation is ``reproduction.identify_axis`` (no PSO) on ``reproduction.sweep_series`` of one
axis: the same records and fits as ``python -m service.reports.reproduction``, so the fitted cells
are the reproduction's. Search: bounded Nelder–Mead on the parameters mapped to [0, 1] (log-mapped
where the bound spans a decade or more), from the bench's current values.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from drivers.emulated.config import load_config
from service.reports.calibration import PAPER, last_cycle, loop_width, run_loops
from service.reports.reproduction import PAPER_TABLE6_UM, identify_axis, sweep_series

TABLE_FREQUENCIES_HZ = (10.0, 100.0)
MODELS = ("dynamic_joint", "grpi", "static")  # Table 6's columns, in the paper's order
CELL_TOLERANCE = 0.35  # each cell within ±35 % of the paper's
REDUCTION_TOLERANCE = 0.15  # dynamic PI's reduction at 10 Hz within 15 points
STROKE_TOLERANCE = 0.03
#: the strain coefficients one stroke factor multiplies (see the module docstring)
STRAIN_KEYS = (
    "piezo.reversible_um_per_v",
    "piezo.hysteresis.switched_um",
    "piezo.asymmetry.electrostrictive_um_per_v2",
    "piezo.asymmetry.saturation_um",
)


@dataclass(frozen=True)
class Parameter:
    """One fitted physical parameter of an axis: its config key under ``axes.<axis>.``, its bound
    and why the bound is physical."""

    key: str
    low: float
    high: float
    why: str

    @property
    def log(self) -> bool:
        return self.low > 0 and self.high / self.low >= 10.0

    def to_unit(self, value: float) -> float:
        value = min(max(value, self.low), self.high)
        if self.log:
            return math.log(value / self.low) / math.log(self.high / self.low)
        return (value - self.low) / (self.high - self.low)

    def from_unit(self, unit: float) -> float:
        unit = min(max(unit, 0.0), 1.0)
        if self.log:
            return self.low * (self.high / self.low) ** unit
        return self.low + unit * (self.high - self.low)


PARAMETERS = (
    Parameter(
        "piezo.rate_dependence.relaxation_s",
        1e-4,
        3e-2,
        "Debye time of the slow domain-wall motion: from 0.1 ms (the bench's former value) to 30 ms, where it "
        "would merge into the creep modes (10 ms to 1000 s)",
    ),
    Parameter(
        "piezo.rate_dependence.relaxing_fraction",
        0.0,
        0.4,
        "share of the switched strain that lags: 0 (none) to 0.4 (at most ~30 % of the stroke lost at high "
        "rate), a cap so that the 100 Hz loop cannot collapse; the fitted value stays well inside it",
    ),
    Parameter(
        "piezo.asymmetry.saturation_um",
        3.0,
        60.0,
        "soft saturation (tanh) scale of the switched strain: 3 µm (strongly saturating at 120 V, "
        "loop visibly bent over) to 60 µm (practically linear)",
    ),
    Parameter(
        "piezo.asymmetry.electrostrictive_um_per_v2",
        0.0,
        3e-5,
        "u² strain: 0 to 3e-5 µm/V², i.e. up to 0.43 µm (5–7 % of the stroke) at 120 V",
    ),
    Parameter("piezo.creep.rate_per_decade", 0.01, 0.02, "log(t) creep: 1–2 % per decade of time"),
    Parameter(
        "flexure.dynamics.damping_ratio",
        0.02,
        0.1,
        "first-mode damping of a bolted, preloaded flexure: from 0.02 (the paper's Table 1 gives Q_m = 45, "
        "ζ ≈ 0.011 for the ceramic alone) to 0.1, the most that still leaves the FEM mode a resonance "
        "(peak ≥ 4× the low-frequency gain, within 2 % of f_n: tests/unit/drivers/test_emulator_stages.py)",
    ),
    Parameter(
        "gauge.bandwidth.bandwidth_hz",
        2e3,
        1e5,
        "capacitance-gauge low-pass: 2–100 kHz, the range such gauge electronics are set to ("
        "0.3–5 nm noise depending on bandwidth; the noise is not refitted)",
    ),
)


def paper_reduction(axis: str) -> float:
    """The paper's dynamic-PI reduction of the static PI's error at 10 Hz (fraction)."""
    dynamic, _, static = PAPER_TABLE6_UM[axis][10.0]
    return 1.0 - dynamic / static


def current_values(axis: str, bench: str = "default") -> dict[str, float]:
    """The bench's present values of ``PARAMETERS`` and ``STRAIN_KEYS`` for ``axis``."""
    cfg = load_config(bench)["axes"][axis]
    out = {}
    for key in {p.key for p in PARAMETERS} | set(STRAIN_KEYS):
        node = cfg
        for part in key.split("."):
            node = node.get(part, {})
        out[key] = float(node) if node != {} else 1.0  # relaxing_fraction is optional, 1 by default
    return out


def overrides_for(axis: str, values: dict[str, float]) -> dict:
    """Dotted config overrides setting ``values`` on ``axis`` (every effect they touch enabled)."""
    return {f"axes.{axis}.{key}": value for key, value in values.items()}


def with_paper_stroke(axis: str, values: dict[str, float], bench: str = "default", seed: int = 0) -> dict[str, float]:
    """``values`` with the strain coefficients scaled so that the 1 Hz stroke (last cycle) is the paper's."""
    _, x = run_loops(bench, seed, (1.0,), overrides_for(axis, values), axes=(axis,))[axis][1.0]
    _, x = last_cycle(x, x, 1.0)
    factor = PAPER[axis]["stroke_um"] / float(np.ptp(x))
    return {**values, **{key: values[key] * factor for key in STRAIN_KEYS}}


def measure_axis(axis: str, values: dict[str, float], bench: str = "default", seed: int = 0) -> dict:
    """Table 6's cells of ``axis`` for ``values`` (stroke held): {"rms_um": {model: {label: µm}},
    "stroke_um", "loop_width_pct", "values"}."""
    values = with_paper_stroke(axis, values, bench, seed)
    loops = sweep_series(bench, seed, overrides_for(axis, values), axes=(axis,))[axis]
    u, x = last_cycle(loops[0].u_v, loops[0].x_um, 1.0)
    stroke = float(np.ptp(x))
    fitted = identify_axis(loops, seed, with_pso=False)
    return {
        "rms_um": fitted["rms_um"],
        "stroke_um": stroke,
        "loop_width_pct": 100.0 * loop_width(u, x) / stroke,
        "values": values,
    }


def cells(rms_um: dict) -> dict[tuple[str, float], float]:
    """{(model, f_hz): RMS µm} for Table 6's models at 10 and 100 Hz."""
    return {(m, f): rms_um[m][f"{f:g} Hz"] for m in MODELS for f in TABLE_FREQUENCIES_HZ}


def target_checks(axis: str, rms_um: dict, stroke_um: float | None = None) -> list[tuple[str, bool, str]]:
    """Every target of issue 18 for one axis: (name, met, figures)."""
    got = cells(rms_um)
    out = []
    for f in TABLE_FREQUENCIES_HZ:
        paper = dict(zip(MODELS, PAPER_TABLE6_UM[axis][f]))
        for m in MODELS:
            ratio = got[(m, f)] / paper[m]
            out.append(
                (
                    f"{axis.upper()} {f:g} Hz {m} within ±35 %",
                    abs(ratio - 1.0) <= CELL_TOLERANCE,
                    f"{got[(m, f)]:.4f} vs {paper[m]:.4f} ({ratio:.2f}×)",
                )
            )
        d, g, s = (got[(m, f)] for m in MODELS)
        out.append((f"{axis.upper()} {f:g} Hz dynamic < GRPI", d < g, f"{d:.4f} < {g:.4f}"))
        if paper["grpi"] <= paper["static"]:
            out.append((f"{axis.upper()} {f:g} Hz GRPI ≤ static", g <= s, f"{g:.4f} ≤ {s:.4f}"))
    red, red_paper = 1.0 - got[("dynamic_joint", 10.0)] / got[("static", 10.0)], paper_reduction(axis)
    out.append(
        (
            f"{axis.upper()} 10 Hz reduction within 15 points",
            abs(red - red_paper) <= REDUCTION_TOLERANCE,
            f"{100 * red:.1f} % vs {100 * red_paper:.1f} %",
        )
    )
    if stroke_um is not None:
        ratio = stroke_um / PAPER[axis]["stroke_um"]
        out.append(
            (
                f"{axis.upper()} 1 Hz stroke within 3 %",
                abs(ratio - 1.0) <= STROKE_TOLERANCE,
                f"{stroke_um:.2f} vs {PAPER[axis]['stroke_um']:.2f} µm",
            )
        )
    return out


#: Weight of the 100 Hz cells' terms: below it no plausible parameter moves them far (the FEM mode
#: and the DAQ's one-sample latency set a floor, see ``flexure_floor_um``), and at full weight a
#: trade-off against an unreachable cell would give up a reachable 10 Hz target.
WEIGHT_100HZ = 0.2
#: Pull towards the centre of a band, so that a met target does not sit on its edge.
CENTRE_PULL = 0.1
#: The static PI's 1 Hz error may differ from the paper's by this factor (the calibration test allows 2).
PI_1HZ_MARGIN = 1.8


def _band(miss: float) -> float:
    """Squared excess beyond a band, in band widths (0 inside), plus a gentle pull to its centre."""
    return max(0.0, abs(miss) - 1.0) ** 2 * 100.0 + CENTRE_PULL * miss**2


def objective(axis: str, measured: dict) -> tuple[float, dict[str, float]]:
    """Sum of terms: each 10 Hz cell's log ratio to the paper's in units of log(1.35) and the 10 Hz
    reduction's miss in units of 15 points (``_band``: steep beyond the target, gentle inside); the
    100 Hz cells' squared log ratios at ``WEIGHT_100HZ``; ordering hinges; and the calibration
    test's 1 Hz guards with a margin (loop width 10.5–14.5 %, static PI at 1 Hz within ``PI_1HZ_MARGIN`` × of the paper's)."""
    got, parts = cells(measured["rms_um"]), {}
    for (m, f), value in got.items():
        paper = PAPER_TABLE6_UM[axis][f][MODELS.index(m)]
        miss = math.log(value / paper) / math.log(1.0 + CELL_TOLERANCE)
        parts[f"{m}@{f:g}"] = _band(miss) if f == 10.0 else WEIGHT_100HZ * miss**2
    red = 1.0 - got[("dynamic_joint", 10.0)] / got[("static", 10.0)]
    parts["reduction@10"] = _band((red - paper_reduction(axis)) / REDUCTION_TOLERANCE)
    for f in TABLE_FREQUENCIES_HZ:
        d, g, s = (got[(m, f)] for m in MODELS)
        parts[f"order_dg@{f:g}"] = 1e4 * max(0.0, math.log(d / g) + 0.02) ** 2
        if PAPER_TABLE6_UM[axis][f][1] <= PAPER_TABLE6_UM[axis][f][2]:
            parts[f"order_gs@{f:g}"] = 1e4 * max(0.0, math.log(g / s) + 0.01) ** 2
    width = measured["loop_width_pct"]
    parts["loop_width"] = (max(0.0, 10.5 - width, width - 14.5)) ** 2
    pi_1hz = measured["rms_um"]["static"]["1 Hz"] / PAPER[axis]["pi_rms_1hz_um"]
    parts["pi_1hz"] = 1e4 * max(0.0, abs(math.log(pi_1hz)) - math.log(PI_1HZ_MARGIN)) ** 2
    return float(sum(parts.values())), parts


def search_unit_box(evaluate, x0: np.ndarray, evaluations: int, step: float) -> None:
    """Bounded Nelder–Mead over parameters scaled to [0, 1], from ``x0`` with a first simplex of
    ``step`` along each axis (inward at a bound); ``evaluate`` keeps the best it sees."""
    simplex = [x0] + [
        np.clip(x0 + np.where(np.arange(len(x0)) == i, step if x0[i] < 1 - step else -step, 0.0), 0, 1)
        for i in range(len(x0))
    ]
    minimize(
        evaluate,
        x0,
        method="Nelder-Mead",
        bounds=[(0.0, 1.0)] * len(x0),
        options={"maxfev": evaluations, "initial_simplex": np.array(simplex), "xatol": 5e-3, "fatol": 1e-3},
    )


def fit_axis(
    axis: str,
    evaluations: int = 150,
    bench: str = "default",
    seed: int = 0,
    log=None,
    start: dict[str, float] | None = None,
    step: float = 0.25,
) -> dict:
    """Bounded Nelder–Mead over ``PARAMETERS`` from ``start`` (default: the bench's values), the initial
    simplex ``step`` wide in the [0, 1] coordinates.
    Returns the best {"objective", "parts", "values", "measured", "evaluations"}."""
    base = current_values(axis, bench)
    if start:
        base.update(start)
    x0 = np.array([p.to_unit(base[p.key]) for p in PARAMETERS])
    best: dict = {"objective": math.inf}
    cache: dict = {}
    began = time.perf_counter()

    def evaluate(unit: np.ndarray) -> float:
        key = tuple(np.round(unit, 4))
        if key in cache:
            return cache[key]
        values = {**base, **{p.key: p.from_unit(u) for p, u in zip(PARAMETERS, unit)}}
        measured = measure_axis(axis, values, bench, seed)
        value, parts = objective(axis, measured)
        cache[key] = value
        record = {
            "n": len(cache),
            "s": round(time.perf_counter() - began, 1),
            "objective": value,
            "values": {p.key: values[p.key] for p in PARAMETERS},
            "cells": {f"{m}@{f:g}": v for (m, f), v in cells(measured["rms_um"]).items()},
            "static_1hz_um": measured["rms_um"]["static"]["1 Hz"],
        }
        if log is not None:
            log.write(json.dumps({"axis": axis, **record}) + "\n")
            log.flush()
        if value < best["objective"]:
            best.update(objective=value, parts=parts, values=measured["values"], measured=measured)
            print(
                f"[{axis} #{len(cache)} {record['s']:.0f} s] objective {value:.3f}: "
                + ", ".join(f"{k} {v:.4f}" for k, v in record["cells"].items()),
                flush=True,
            )
        return value

    search_unit_box(evaluate, x0, evaluations, step)
    best["evaluations"] = len(cache)
    return best


def toml_lines(axis: str, values: dict[str, float]) -> list[str]:
    """The fitted values as ``key = value`` lines per table of fixtures/benches/default.toml."""
    tables: dict[str, list[str]] = {}
    for key in sorted(values):
        table, leaf = key.rsplit(".", 1)
        tables.setdefault(f"axes.{axis}.{table}", []).append(f"{leaf} = {values[key]:.4g}")
    return [line for table, leaves in tables.items() for line in [f"[{table}]", *leaves]]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m service.reports.calibration --fit",
        description="Fit the bench's physical parameters to the paper's Table 6.",
    )
    parser.add_argument("--fit", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--axis", choices=("y", "z"), action="append", help="axis to fit (default: both)")
    parser.add_argument("--evaluations", type=int, default=150, help="sweeps per axis (each ≈ 2–3 s)")
    parser.add_argument("--bench", default="default")
    parser.add_argument("--step", type=float, default=0.25, help="initial simplex size in [0, 1] coordinates")
    parser.add_argument("--log", help="append every evaluation as a JSON line to this file")
    parser.add_argument(
        "--start",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="start the search here instead of the bench's value (KEY under axes.<axis>.)",
    )
    args = parser.parse_args(argv)
    start = {}
    for item in args.start:
        key, _, value = item.partition("=")
        if key not in {p.key for p in PARAMETERS}:
            parser.error(f"--start: {key!r} is not a fitted parameter ({', '.join(p.key for p in PARAMETERS)})")
        start[key] = float(value)
    log = open(args.log, "a") if args.log else None
    try:
        for axis in args.axis or ("y", "z"):
            best = fit_axis(axis, args.evaluations, args.bench, log=log, start=start, step=args.step)
            print(f"\n{axis.upper()}: objective {best['objective']:.3f} after {best['evaluations']} evaluations")
            for name, value in sorted(best["parts"].items(), key=lambda kv: -kv[1]):
                print(f"  {name:16s} {value:8.3f}")
            for name, met, figures in target_checks(axis, best["measured"]["rms_um"], best["measured"]["stroke_um"]):
                print(f"  [{'x' if met else ' '}] {name}: {figures}")
            print("\n".join(toml_lines(axis, best["values"])))
    finally:
        if log is not None:
            log.close()
    return 0
