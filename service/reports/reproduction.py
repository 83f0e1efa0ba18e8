"""Reproduce the paper's Table 6 on the emulated bench: static PI, GRPI and dynamic PI RMS errors.

Run ``python -m service.reports.reproduction`` to sweep Y and Z at 1, 10, 50 and 100 Hz (0–120 V biased
sine, 5 cycles, 20 kHz) on the default and paper_measured benches, identify the three models the way the
paper did, print the tables beside the paper's figures and write docs/reproduction.md (``--bench NAME``:
one bench, printed; service/reports/reproduction_benches.py).

How each model is identified (paper §2.3):
- static PI: 10 operators (0, 6, …, 54 V), weights ≥ 0 by least squares on the 1 Hz loop only;
- GRPI: envelope (a1, a2, b1, b2) by variable projection, weights ≥ 0, on all four loops;
- dynamic PI: ω, α1..4, β1..4 on all four loops — exactly by least squares (joint), and by the
  paper's two procedures (ω on 1 Hz, then α, β by least squares or by PSO).
Every RMS is over the whole 5-cycle record of that frequency.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from drivers.emulated.config import load_config
from service.reports.calibration import CYCLES, FREQUENCIES_HZ, SAMPLE_RATE_HZ, run_loops
from service.science import paper
from service.science.data.record import Record
from service.science.data.signals import biased_sine
from service.science.fitting.metrics import rms
from service.science.models import GRPI, StaticPI
from service.science.models.procedures import fit_dynamic_pi_pso, fit_dynamic_pi_two_stage, identify

ROOT = Path(__file__).resolve().parents[2]
#: Table 6 of the paper, RMS error in µm: {axis: {f_hz: (dynamic PI, GRPI, static PI)}}.
PAPER_TABLE6_UM = paper.TABLE6_RMS_UM
MODEL_COLUMNS = ("dynamic_joint", "dynamic_two_stage", "dynamic_pso", "grpi", "static")


#: Cumulative switches for the ablation: which emulated effects explain the gap to the paper.
ABLATION_STEPS = (
    ("default bench", ()),
    ("flexure dynamics off", ("flexure.dynamics",)),
    ("… and creep off", ("flexure.dynamics", "piezo.creep")),
    ("… and asymmetry off", ("flexure.dynamics", "piezo.creep", "piezo.asymmetry")),
    ("… and relaxation off", ("flexure.dynamics", "piezo.creep", "piezo.asymmetry", "piezo.rate_dependence")),
)


def _switched_off(paths: tuple[str, ...]) -> dict:
    """Config overrides that disable ``paths`` (e.g. "piezo.creep") on both axes."""
    overrides: dict = {"axes": {}}
    for axis in ("y", "z"):
        node = overrides["axes"].setdefault(axis, {})
        for path in paths:
            parts = path.split(".")
            cursor = node
            for part in parts:
                cursor = cursor.setdefault(part, {})
            cursor["enabled"] = False
    return overrides


def sweep_series(
    bench_name: str = "default", seed: int = 0, overrides: dict | None = None, axes: tuple[str, ...] = ("y", "z")
) -> dict[str, list[Record]]:
    """Per axis, one Record per frequency, with the commanded waveform's exact derivatives."""
    loops = run_loops(bench_name, seed=seed, overrides=overrides, axes=axes)
    out: dict[str, list[Record]] = {}
    for axis, by_frequency in loops.items():
        out[axis] = []
        for f_hz in FREQUENCIES_HZ:
            u_v, x_um = by_frequency[f_hz]
            wave = biased_sine(f_hz, CYCLES, SAMPLE_RATE_HZ)
            out[axis].append(
                Record(
                    u_v,
                    x_um,
                    SAMPLE_RATE_HZ,
                    du_v_per_s=wave.d1_per_s,
                    ddu_v_per_s2=wave.d2_per_s2,
                    label=f"{f_hz:g} Hz",
                )
            )
    return out


def _rms(model, record: Record) -> float:
    return rms(record.x_um - model.predict(record))


def identify_axis(loops: list[Record], seed: int = 0, with_pso: bool = True) -> dict:
    """Fit every model of the table to one axis's loops; returns RMS per model per frequency."""
    one_hz = loops[0]
    timings: dict[str, float] = {}

    def timed(name, fit):
        start = time.perf_counter()
        model = fit()
        timings[name] = time.perf_counter() - start
        return model

    models = {
        "static": timed("static", lambda: StaticPI().fit(one_hz)),
        "grpi": timed("grpi", lambda: GRPI().fit(loops)),
        "dynamic_joint": timed("dynamic_joint", lambda: identify("dynamic_pi", loops)),
        "dynamic_two_stage": timed("dynamic_two_stage", lambda: fit_dynamic_pi_two_stage(loops, static_data=one_hz)),
    }
    if with_pso:
        models["dynamic_pso"] = timed(
            "dynamic_pso", lambda: fit_dynamic_pi_pso(loops, static_data=one_hz, seed=seed)[0]
        )
    rms = {name: {s.label: _rms(model, s) for s in loops} for name, model in models.items()}
    return {"rms_um": rms, "fit_s": timings}


def reproduce(bench_name: str = "default", seed: int = 0, with_pso: bool = True) -> dict:
    """Sweep, identify and tabulate both axes. Returns {axis: identify_axis(...)}."""
    return {axis: identify_axis(loops, seed, with_pso) for axis, loops in sweep_series(bench_name, seed).items()}


def ablation(bench_name: str = "default", seed: int = 0) -> list[tuple[str, dict]]:
    """Table 6's models again with emulated effects switched off step by step (no PSO)."""
    return [
        (
            label,
            {
                axis: identify_axis(loops, seed, with_pso=False)
                for axis, loops in sweep_series(bench_name, seed, _switched_off(paths)).items()
            },
        )
        for label, paths in ABLATION_STEPS
    ]


def _ablation_reading(steps: list[tuple[str, dict]], bench_name: str = "default") -> str:
    """The ablation's lessons, quoted from its own numbers."""
    rms = {label: result for label, result in steps}

    def cell(label, axis, f_hz, model="dynamic_joint"):
        return rms[label][axis]["rms_um"][model][f"{f_hz:g} Hz"]

    def reduction(label, axis):
        return 100.0 * (1.0 - cell(label, axis, 10) / cell(label, axis, 10, "static"))

    first, no_flex, no_creep, no_asym, no_relax = (label for label, _ in steps)
    rd = {axis: load_config(bench_name)["axes"][axis]["piezo"]["rate_dependence"] for axis in ("y", "z")}
    relax = {axis: (v["relaxation_s"], v.get("relaxing_fraction", 1.0)) for axis, v in rd.items()}
    return (
        "\n".join(
            [
                "",
                f"- **100 Hz is the flexure.** The emulated modes sit at the paper's FEM figures (482.6 and 290.7 Hz); a "
                f"100 Hz drive is amplified by the mode (r²/(1 − r²) of the fundamental at any damping) and its harmonics "
                f"ring it (Z's third, at 300 Hz, sits on the mode). No PI-family model has structural dynamics, so the "
                f"dynamic PI leaves {cell(first, 'z', 100):.3f} µm on Z; with the flexure's dynamics switched off it "
                f"leaves {cell(no_flex, 'z', 100):.3f} µm (paper 0.104 µm). Y at 100 Hz falls likewise from "
                f"{cell(first, 'y', 100):.3f} to {cell(no_flex, 'y', 100):.3f} µm. docs/calibration.md quantifies the floor.",
                f"- **At 10 Hz the dynamic PI follows the relaxation.** The emulated stack relaxes a fraction of its "
                f"switched strain (Y: {relax['y'][1]:.2f} of it with τ = {1e3 * relax['y'][0]:.2g} ms; Z: {relax['z'][1]:.2f} "
                f"with τ = {1e3 * relax['z'][0]:.2g} ms; docs/calibration.md gives the sources), so the 10 Hz loop is smaller "
                f"and wider than the 1 Hz loop the static PI was fitted on, and the dynamic PI's u̇- and ü-dependent weights "
                f"follow it. It removes {reduction(first, 'y'):.0f} % (Y) and {reduction(first, 'z'):.0f} % (Z) of the static "
                f"PI's 10 Hz error on the default bench (paper 41 % and 36 %). With flexure, creep and asymmetry off, Z's "
                f"static PI leaves {cell(no_asym, 'z', 10, 'static'):.4f} µm at 10 Hz, and "
                f"{cell(no_relax, 'z', 10, 'static'):.4f} µm once the relaxation is off too.",
                f"- **Asymmetry sets the 1 Hz floor.** Electrostriction (∝ u²) and saturation make the emulated loop "
                f"non-centrosymmetric, which no symmetric operator fits: switching them off drops the static PI's 10 Hz "
                f"error on Y from {cell(no_creep, 'y', 10, 'static'):.4f} to {cell(no_asym, 'y', 10, 'static'):.4f} µm.",
                f"- **Creep adds a few hundredths of a µm** over a 5-cycle record (Y 10 Hz, dynamic PI: "
                f"{cell(no_flex, 'y', 10):.4f} → {cell(no_creep, 'y', 10):.4f} µm).",
                f"- **With only hysteresis left** (last row) the rate-dependent models sit near the noise and the "
                f"Preisach-versus-PI floor (Y 10 Hz: dynamic {cell(no_relax, 'y', 10):.4f}, static "
                f"{cell(no_relax, 'y', 10, 'static'):.4f} µm); at 100 Hz the static PI still leaves "
                f"{cell(no_relax, 'y', 100, 'static'):.4f} µm on Y: the DAQ's one-sample latency and the amplifier's and "
                f"gauge's bandwidths, a lag the rate-dependent models absorb and a 1 Hz static PI cannot.",
                "- These residuals are what the discovery workflow attributes to the `dynamics`, `asymmetry`, `creep` and "
                "`rate_dependence` effects.",
            ]
        )
        + "\n"
    )


def render_ablation(steps: list[tuple[str, dict]], bench_name: str = "default") -> str:
    """Markdown: RMS (µm) of dynamic PI / GRPI / static PI at 10 and 100 Hz per ablation step."""
    lines = [
        "## Which emulated physics makes the difference (ablation)",
        "",
        "The same sweep and fits with emulated effects switched off cumulatively. Cells: dynamic PI (exact LS) / "
        "GRPI / static PI, RMS in µm. Paper: Y 10 Hz 0.0586 / 0.0933 / 0.0991, Y 100 Hz 0.0812 / 0.0985 / 0.1075, "
        "Z 10 Hz 0.0901 / 0.1449 / 0.1406, Z 100 Hz 0.1039 / 0.1326 / 0.1513.",
        "",
        "| emulator | Y 10 Hz | Y 100 Hz | Z 10 Hz | Z 100 Hz |",
        "|---|---|---|---|---|",
    ]
    for label, result in steps:
        cells = []
        for axis in ("y", "z"):
            for f_hz in (10.0, 100.0):
                rms = result[axis]["rms_um"]
                cells.append(" / ".join(f"{rms[m][f'{f_hz:g} Hz']:.4f}" for m in ("dynamic_joint", "grpi", "static")))
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n" + _ablation_reading(steps, bench_name)


def render_markdown(result: dict, bench_name: str = "default", seed: int = 0) -> str:
    """docs/reproduction.md: the table in the paper's layout, beside the paper's figures."""
    lines = [
        "# The paper's Table 6, reproduced on the emulated bench",
        "",
        f"Produced by `python -m service.reports.reproduction` (bench `{bench_name}`, seed {seed}). Drive: "
        "u = 60 − 60 cos(2πft) V, 5 cycles at 20 kHz, each axis alone with the other at 0 V. "
        "RMS error over the whole record, µm. Static PI fitted on the 1 Hz loop (as the paper); "
        "GRPI and dynamic PI on the 1, 10, 50 and 100 Hz loops together. The dynamic PI is solved "
        "three ways: exactly by joint least squares (ω ≥ 0), by the paper's two stages with α, β "
        "by least squares, and by the paper's PSO (N = M = 100, w = 0.5, c1 = c2 = 2).",
        "",
        "| axis | frequency | dynamic PI (exact LS) | dynamic PI (two-stage) | dynamic PI (PSO) | GRPI | static PI | "
        "paper: dynamic / GRPI / static |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for axis in ("y", "z"):
        rms = result[axis]["rms_um"]
        for f_hz in FREQUENCIES_HZ:
            label = f"{f_hz:g} Hz"
            paper = PAPER_TABLE6_UM[axis].get(f_hz)
            paper_text = " / ".join(f"{v:.4f}" for v in paper) if paper else "—"
            cells = " | ".join(f"{rms[m][label]:.4f}" for m in MODEL_COLUMNS)
            lines.append(f"| {axis.upper()} | {label} | {cells} | {paper_text} |")
    lines += [
        "",
        "Fit times (s): "
        + "; ".join(
            f"{axis.upper()}: " + ", ".join(f"{k} {v:.2f}" for k, v in result[axis]["fit_s"].items())
            for axis in ("y", "z")
        ),
        "",
        _discussion(result),
    ]
    return "\n".join(lines) + "\n"


def _discussion(result: dict) -> str:
    def mean(axis, model, freqs=(10.0, 100.0)):
        return float(np.mean([result[axis]["rms_um"][model][f"{f:g} Hz"] for f in freqs]))

    holds = [
        f"{axis.upper()} {f:g} Hz"
        for axis in ("y", "z")
        for f in (10.0, 100.0)
        if mean(axis, "dynamic_joint", (f,)) < mean(axis, "grpi", (f,)) <= mean(axis, "static", (f,)) * 1.0001
    ]
    fails = [
        f"{axis.upper()} {f:g} Hz"
        for axis in ("y", "z")
        for f in (10.0, 100.0)
        if f"{axis.upper()} {f:g} Hz" not in holds
    ]
    y_order = [mean("y", m) for m in ("dynamic_joint", "grpi", "static")]
    return "\n".join(
        [
            "## Reading the table",
            "",
            f"- **Ordering.** The paper's ordering, dynamic < GRPI ≤ static, holds at {', '.join(holds) or 'no cell'}"
            + (f" and not at {', '.join(fails)}" if fails else "")
            + f". On Y the mean over 10 and 100 Hz is {y_order[0]:.4f} µm (dynamic PI), {y_order[1]:.4f} µm (GRPI) and "
            f"{y_order[2]:.4f} µm (static PI).",
            "- **The exact solution is the optimum.** The dynamic PI is linear in ω, α and β once the play-operator "
            "outputs are known, so joint least squares reaches the lowest error the model can; the paper's two-stage "
            "procedure fixes ω on the 1 Hz loop and cannot do better, and PSO converges towards the two-stage optimum "
            "(see `evcbench bench identification --json` for speed: least squares is over 100× faster).",
            "- **Where the emulator differs from the paper, and why:** see the ablation below, which switches the "
            "emulator's effects off one by one.",
        ]
    )


def main(argv: list[str] | None = None) -> int:
    """Both benches (``default``, ``paper_measured``) or those named by ``--bench``: see reproduction_benches."""
    from service.reports.reproduction_benches import main as run

    return run(sys.argv[1:] if argv is None else argv)


if __name__ == "__main__":
    sys.exit(main())
