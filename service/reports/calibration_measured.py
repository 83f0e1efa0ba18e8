"""Fit the ``paper_measured`` bench (the device as the paper measured it) to Table 6 and the 1 Hz loop.

    python -m service.reports.calibration_measured [--axis y|z] [--evaluations N] [--log FILE]

The project's method (service/reports/calibration_fit.py): per axis, a bounded Nelder–Mead over
physical parameters mapped to [0, 1] inside stated bounds, each evaluation the reproduction's own
sweep (1, 10, 50, 100 Hz, 0–120 V, 5 cycles) with the strain coefficients scaled so that the 1 Hz
stroke is the paper's. What differs from ``calibration_fit`` (which fits ``default``):

- the first mode is fitted too (``flexure.resonance_hz``, from the FEM's figure up): the measured
  100 Hz cells, not the FEM, place it; and so is the amplifier's small-signal bandwidth;
- the electrostriction's bound reaches higher (the static PI's 1 Hz error is held near the paper's,
  which is loop shape once creep is small), and the creep bound lower (the paper's static PI error grows by 6 % from 1 to 100 Hz on Z:
  a 1 Hz record cannot carry much more creep than a 50 ms one);
- the static and dynamic PI's 8 cells of Table 6 count in full, in units of log 1.25 (a margin inside
  the ±35 % target),
  with the 1 Hz loop width (10.5–14.5 %) and the static PI's 1 Hz error (within 1.8× of the paper's);
  the dynamic PI's 10 Hz reduction is a gentle pull, not a band;
- the search fits the static and dynamic PI only; the GRPI (45–120 s per fit, 20× the rest) is fitted
  on the result, by ``python -m service.reports.reproduction --bench paper_measured``. At 100 Hz it sits
  just below the static PI (0.96–0.99× on a first fit), so the static PI's 100 Hz error is also held
  below 1.25× the paper's GRPI cell.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

from drivers.emulated.config import load_config
from service.reports.calibration import PAPER, last_cycle, loop_width, run_loops
from service.reports.calibration_fit import (
    PARAMETERS,
    PI_1HZ_MARGIN,
    STRAIN_KEYS,
    Parameter,
    _band,
    overrides_for,
    search_unit_box,
)
from service.reports.reproduction import PAPER_TABLE6_UM, sweep_series
from service.science import paper
from service.science.fitting.metrics import rms
from service.science.models import StaticPI
from service.science.models.procedures import identify

BENCH = "paper_measured"
#: the search's band per cell: log ratio in units of log(1 + BAND) (the target is ±35 %)
BAND = 0.25
#: the 1 Hz loop width the search keeps to (% of the stroke; the calibration test allows 10–15 %)
LOOP_WIDTH_PCT = (10.5, 14.5)
SEARCHED_MODELS = ("dynamic_joint", "static")
#: weight of the 10 Hz reduction (the paper's 41 / 36 %): a pull, not a target (the cells are the target)
REDUCTION_WEIGHT = 0.5
FREQUENCIES = (10.0, 100.0)
#: bounds that differ from calibration_fit.PARAMETERS for this bench
CREEP = Parameter(
    "piezo.creep.rate_per_decade",
    0.002,
    0.02,
    "log(t) creep, 0.2–2 % per decade: the paper's static PI error barely grows from 1 to 100 Hz "
    "(Y 0.0881 → 0.1075, Z 0.1432 → 0.1513 µm), which a 5 s record's creep would not allow above ~1 %",
)
AMPLIFIER = Parameter(
    "amplifier.bandwidth.bandwidth_hz",
    5e3,
    2e4,
    "small-signal bandwidth of the amplifier channel into the 1.8 µF stack: 5 kHz (the default's) to 20 kHz",
)


ELECTROSTRICTION = Parameter(
    "piezo.asymmetry.electrostrictive_um_per_v2",
    0.0,
    6e-5,
    "u² strain: 0 to 6e-5 µm/V², up to 0.86 µm (9–13 % of the stroke) at 120 V: with little creep, the "
    "paper's static PI error at 1 Hz (Z 0.1432 µm, 1.8× the default bench's) is loop shape its "
    "centrosymmetric operators miss",
)


def mode_parameter(axis: str) -> Parameter:
    """The first mode (Hz), from the FEM's figure to 4× it: where the measured cells put it."""
    fem = paper.FEM_FIRST_MODE_HZ[axis]
    return Parameter(
        "flexure.resonance_hz",
        fem,
        4.0 * fem,
        f"first mode along the drive: from the FEM's {fem:g} Hz (the flexure body alone) up; "
        "the measured 100 Hz cells place it (the fixture's comment says why it sits above the FEM)",
    )


def parameters(axis: str) -> tuple[Parameter, ...]:
    """The fitted parameters of ``axis`` on this bench."""
    wider = {p.key: p for p in (CREEP, ELECTROSTRICTION)}
    base = tuple(wider.get(p.key, p) for p in PARAMETERS)
    return base + (mode_parameter(axis), AMPLIFIER)


def current_values(axis: str, bench: str = BENCH) -> dict[str, float]:
    """The bench's present values of the fitted parameters and the strain coefficients of ``axis``."""
    cfg = load_config(bench)["axes"][axis]
    out = {}
    for key in {p.key for p in parameters(axis)} | set(STRAIN_KEYS):
        node = cfg
        for part in key.split("."):
            node = node.get(part, {})
        out[key] = float(node) if node != {} else 1.0
    return out


def with_paper_stroke(axis: str, values: dict[str, float], bench: str = BENCH, seed: int = 0) -> dict[str, float]:
    """``values`` with the strain coefficients scaled so that the 1 Hz stroke (last cycle) is the paper's."""
    _, x = run_loops(bench, seed, (1.0,), overrides_for(axis, values), axes=(axis,))[axis][1.0]
    factor = PAPER[axis]["stroke_um"] / float(np.ptp(last_cycle(x, x, 1.0)[1]))
    return {**values, **{key: values[key] * factor for key in STRAIN_KEYS}}


def measure(axis: str, values: dict[str, float], bench: str = BENCH, seed: int = 0) -> dict:
    """The searched cells of ``axis`` (static PI on the 1 Hz loop, dynamic PI jointly on all four, RMS µm
    per record as the reproduction computes them), the 1 Hz stroke (µm) and loop width (%)."""
    values = with_paper_stroke(axis, values, bench, seed)
    loops = sweep_series(bench, seed, overrides_for(axis, values), axes=(axis,))[axis]
    models = {"static": StaticPI().fit(loops[0]), "dynamic_joint": identify("dynamic_pi", loops)}
    rms_um = {m: {s.label: rms(s.x_um - model.predict(s)) for s in loops} for m, model in models.items()}
    u, x = last_cycle(loops[0].u_v, loops[0].x_um, 1.0)
    stroke = float(np.ptp(x))
    return {
        "rms_um": rms_um,
        "stroke_um": stroke,
        "loop_width_pct": 100.0 * loop_width(u, x) / stroke,
        "values": values,
    }


def objective(axis: str, measured: dict) -> tuple[float, dict[str, float]]:
    """Sum of terms: each searched cell's log ratio to Table 6 in units of log(1 + BAND) through ``_band``
    (steep beyond the band, a gentle pull to its centre); the dynamic PI's 10 Hz reduction of the static
    PI's error, squared in units of 15 points at ``REDUCTION_WEIGHT``; hinges on dynamic < static, on the
    loop width and on the static PI's 1 Hz error (within ``PI_1HZ_MARGIN``× of §2.3.1's, as for default)."""
    rms_um, parts = measured["rms_um"], {}
    unit = math.log(1.0 + BAND)
    for f in FREQUENCIES:
        table = dict(zip(("dynamic_joint", "grpi", "static"), PAPER_TABLE6_UM[axis][f]))
        for m in SEARCHED_MODELS:
            parts[f"{m}@{f:g}"] = _band(math.log(rms_um[m][f"{f:g} Hz"] / table[m]) / unit)
        if f == 100.0:  # the GRPI, not searched, sits just below the static PI here (0.96–0.99× on a first fit)
            grpi_ceiling = table["grpi"] * (1.0 + BAND)
            parts["static_as_grpi@100"] = (
                100.0 * max(0.0, math.log(rms_um["static"]["100 Hz"] / grpi_ceiling) / unit) ** 2
            )
        d, s = rms_um["dynamic_joint"][f"{f:g} Hz"], rms_um["static"][f"{f:g} Hz"]
        parts[f"order@{f:g}"] = 1e4 * max(0.0, math.log(d / s) + 0.1) ** 2
    pi_1hz = abs(math.log(rms_um["static"]["1 Hz"] / PAPER[axis]["pi_rms_1hz_um"]))
    parts["static@1"] = 1e4 * max(0.0, pi_1hz - math.log(PI_1HZ_MARGIN)) ** 2
    dynamic, _, static = PAPER_TABLE6_UM[axis][10.0]
    reduction = 1.0 - rms_um["dynamic_joint"]["10 Hz"] / rms_um["static"]["10 Hz"]
    parts["reduction@10"] = REDUCTION_WEIGHT * ((reduction - (1.0 - dynamic / static)) / 0.15) ** 2
    low, high = LOOP_WIDTH_PCT
    parts["loop_width"] = max(0.0, low - measured["loop_width_pct"], measured["loop_width_pct"] - high) ** 2
    return float(sum(parts.values())), parts


def fit_axis(axis: str, evaluations: int = 150, bench: str = BENCH, seed: int = 0, log=None, step: float = 0.25):
    """Bounded Nelder–Mead from the bench's values. Returns the best {"objective", "parts", "values", "measured"}."""
    params = parameters(axis)
    base = current_values(axis, bench)
    x0 = np.array([p.to_unit(base[p.key]) for p in params])
    best: dict = {"objective": math.inf}
    cache: dict = {}
    began = time.perf_counter()

    def evaluate(unit: np.ndarray) -> float:
        key = tuple(np.round(unit, 4))
        if key not in cache:
            values = {**base, **{p.key: p.from_unit(u) for p, u in zip(params, unit)}}
            measured = measure(axis, values, bench, seed)
            value, parts = objective(axis, measured)
            cache[key] = value
            line = {"axis": axis, "n": len(cache), "s": round(time.perf_counter() - began, 1), "objective": value}
            line |= {"values": measured["values"], "rms_um": measured["rms_um"], "width": measured["loop_width_pct"]}
            if log is not None:
                log.write(json.dumps(line) + "\n")
                log.flush()
            if value < best["objective"]:
                best.update(objective=value, parts=parts, values=measured["values"], measured=measured)
                print(f"[{axis} #{len(cache)} {line['s']:.0f} s] {value:.3f} " + _cells_text(measured), flush=True)
        return cache[key]

    search_unit_box(evaluate, x0, evaluations, step)
    return best


def _cells_text(measured: dict) -> str:
    r = measured["rms_um"]
    cells = ", ".join(f"{m} {f:g} Hz {r[m][f'{f:g} Hz']:.4f}" for f in FREQUENCIES for m in SEARCHED_MODELS)
    return f"{cells}; static 1 Hz {r['static']['1 Hz']:.4f}; width {measured['loop_width_pct']:.1f} %"


def toml_text(axis: str, values: dict[str, float]) -> str:
    """The fitted values as TOML tables of ``axes.<axis>``."""
    tables: dict[str, list[str]] = {}
    for table, leaf in sorted(key.rsplit(".", 1) for key in values):
        tables.setdefault(f"axes.{axis}.{table}", []).append(f"{leaf} = {values[f'{table}.{leaf}']:.5g}")
    return "\n".join(line for table, leaves in tables.items() for line in ["", f"[{table}]", *leaves])


SECTION = "paper_measured calibration"


def doc_section(bench: str = BENCH, seed: int = 0) -> str:
    """docs/calibration.md's section on ``bench``: why its modes differ from the FEM, every fitted value
    beside the default bench's with its bound, and the 1 Hz loop measured as the report above measures it."""
    from service.reports.calibration import measure_calibration
    from service.reports.calibration_notes import flexure_floor_um

    cfg, default = load_config(bench), load_config("default")
    floors = {axis: flexure_floor_um(axis, bench) for axis in ("y", "z")}
    lines = [
        "## The paper's measured device (`paper_measured`)",
        "",
        "`default` is the device as designed: its first modes are the FEM's (482.6 and 290.7 Hz), and above "
        "they keep its 100 Hz cells out of Table 6's reach. `fixtures/benches/paper_measured.toml` is the device "
        "as the paper measured it: the same stacks, amplifier, DAQ and gauges, its first modes where the measured "
        "100 Hz cells put them. **Why they differ from the FEM:** Table 6's static PI leaves 0.1513 µm on Z at "
        "100 Hz, which no mode at 290.7 Hz allows (≥ 0.441 µm, above); a modal analysis of the flexure body "
        "finds its lowest mode, which need not be the one the stack drives along its axis, and it leaves out the "
        "preloaded stacks, whose stiffness acts along that axis and raises the driven mode. So each mode is "
        "fitted, bounded below by the FEM's figure. The hysteresis stays a Preisach model.",
        "",
        f"Fitted by `python -m service.reports.calibration_measured` (module `service/reports/calibration_measured.py`): "
        "the method above (bounded Nelder–Mead, the reproduction's sweep, the 1 Hz stroke held to the paper's), "
        f"over the parameters below, against all 12 cells of Table 6 (static and dynamic PI in the search, each "
        f"in units of log {1 + BAND:g}), the static PI's 1 Hz error, the 1 Hz loop width "
        f"({LOOP_WIDTH_PCT[0]:g}–{LOOP_WIDTH_PCT[1]:g} %) and the dynamic PI's 10 Hz reduction; the GRPI is "
        "fitted on the result. Table 6 on both benches: docs/reproduction.md.",
        "",
        "| parameter (`axes.<axis>.…`) | Y | Z | Y default | Z default | bound | why |",
        "|---|---|---|---|---|---|---|",
    ]
    for p in parameters("y"):
        got = [_value(cfg, a, p.key) for a in ("y", "z")] + [_value(default, a, p.key) for a in ("y", "z")]
        mode = p.key == "flexure.resonance_hz"
        bound = "FEM – 4× FEM" if mode else f"{p.low:g}–{p.high:g}"
        why = (
            "first mode along the drive: the measured 100 Hz cells bound it from below (Z ≥ 486 Hz, above); "
            "well above that it costs a 100 Hz drive < 1 %, so its value is where the search settled"
            if mode
            else p.why
        )
        lines.append(f"| `{p.key}` | " + " | ".join(f"{v:.4g}" for v in got) + f" | {bound} | {why} |")
    for key in (k for k in STRAIN_KEYS if k not in {p.key for p in parameters("y")}):
        got = [_value(cfg, a, key) for a in ("y", "z")] + [_value(default, a, key) for a in ("y", "z")]
        lines.append(
            f"| `{key}` | "
            + " | ".join(f"{v:.4g}" for v in got)
            + " | — | scaled with the two asymmetry keys above: 1 Hz stroke held |"
        )
    measured = measure_calibration(bench, seed)["axes"]
    lines += [
        "",
        "| 1 Hz loop (seed 0) | Y | Y paper | Z | Z paper |",
        "|---|---|---|---|---|",
        "| stroke (µm) | {:.2f} | {:.2f} | {:.2f} | {:.2f} |".format(
            measured["y"]["stroke_um"], PAPER["y"]["stroke_um"], measured["z"]["stroke_um"], PAPER["z"]["stroke_um"]
        ),
        "| loop width (% of stroke) | {:.1f} | 10–15 | {:.1f} | 10–15 |".format(
            measured["y"]["loop_width_pct"], measured["z"]["loop_width_pct"]
        ),
        "| static PI RMS, 1 Hz fit on 1 Hz (µm) | {:.4f} | {:.4f} | {:.4f} | {:.4f} |".format(
            measured["y"]["pi_rms_1hz_um"],
            PAPER["y"]["pi_rms_1hz_um"],
            measured["z"]["pi_rms_1hz_um"],
            PAPER["z"]["pi_rms_1hz_um"],
        ),
        "",
        "What the fitted modes cost a 1 Hz static PI at 100 Hz, at any damping (r²/(1 − r²) of the "
        "fundamental): "
        + "; ".join(
            f"{a.upper()} {100 * floors[a]['gain_excess']:.1f} % at r = {floors[a]['r']:.3f}, "
            f"{floors[a]['flexure_rms_um']:.3f} µm"
            for a in ("y", "z")
        )
        + ".",
    ]
    return "\n".join(lines) + "\n"


def _value(cfg: dict, axis: str, key: str) -> float:
    node = cfg["axes"][axis]
    for part in key.split("."):
        node = node.get(part, 1.0) if isinstance(node, dict) else node
    return float(node)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m service.reports.calibration_measured", description=__doc__)
    parser.add_argument("--axis", choices=("y", "z"), action="append", help="axis to fit (default: both)")
    parser.add_argument("--evaluations", type=int, default=150, help="sweeps per axis (each ≈ 3–5 s)")
    parser.add_argument("--bench", default=BENCH)
    parser.add_argument("--step", type=float, default=0.25, help="initial simplex size in [0, 1] coordinates")
    parser.add_argument("--log", help="append every evaluation as a JSON line to this file")
    parser.add_argument("--doc", action="store_true", help="no fit: write docs/calibration.md's section on the bench")
    args = parser.parse_args(argv)
    if args.doc:
        from service.reports.calibration import ROOT
        from service.reports.doc_sections import write_section

        write_section(ROOT / "docs" / "calibration.md", SECTION, doc_section(args.bench))
        return 0
    log = open(args.log, "a") if args.log else None
    try:
        for axis in args.axis or ("y", "z"):
            best = fit_axis(axis, args.evaluations, args.bench, log=log, step=args.step)
            print(f"\n{axis.upper()}: objective {best['objective']:.3f}")
            for name, value in sorted(best["parts"].items(), key=lambda kv: -kv[1]):
                print(f"  {name:16s} {value:8.3f}")
            print(toml_text(axis, best["values"]))
    finally:
        if log is not None:
            log.close()
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
