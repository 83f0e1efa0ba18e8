"""Calibration of the emulated bench against the seed paper (Zhang et al. 2023).

``measure_calibration`` runs the paper's characterisation on an emulated bench: a 0–120 V
biased sine u = 60 − 60 cos(2πft) from 0 V, 5 cycles at 20 kHz, one axis at a time (as the
paper did), at 1, 10, 50 and 100 Hz. It reports per axis the stroke and loop width (last
cycle) and the RMS error of the paper's static PI (10 play operators, thresholds 0, 6, …, 54 V,
non-negative weights by NNLS, free offset) fitted on the 1 Hz loop.

``python -m service.reports.calibration`` writes docs/calibration.md and docs/img/calibration_loops.png.

The play operator here is a self-contained reference for calibration only; the emulator never
uses it (its hysteresis is a Preisach model).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.optimize import nnls

from service.science import paper
from service.science.data import signals
from service.science.fitting.metrics import rms
from service.science.models.kernels import play_operators as play_outputs

SAMPLE_RATE_HZ = 20000.0
FREQUENCIES_HZ = (1.0, 10.0, 50.0, 100.0)
CYCLES = 5
THRESHOLDS_V = np.arange(10) * 6.0
STATIC = paper.TABLE6_MODELS.index("static_pi")
PAPER = {  # paper values: PI weight sums -> strokes at 120 V; Table 6 and §2.3.1 RMS errors (µm)
    axis: {
        "stroke_um": paper.STROKE_AT_120V_UM[axis],
        "pi_rms_1hz_um": paper.STATIC_PI_1HZ_RMS_UM[axis],
        "pi_rms_10hz_um": paper.TABLE6_RMS_UM[axis][10.0][STATIC],
        "pi_rms_100hz_um": paper.TABLE6_RMS_UM[axis][100.0][STATIC],
    }
    for axis in ("y", "z")
}
ROOT = Path(__file__).resolve().parents[2]


def fit_static_pi(u: np.ndarray, x: np.ndarray, thresholds: np.ndarray = THRESHOLDS_V):
    """Weights ≥ 0 (NNLS) and a free offset for x ≈ P(u)·w + c. Returns (w, c)."""
    p = play_outputs(np.ascontiguousarray(u, dtype=float), np.asarray(thresholds, dtype=float))
    a = np.column_stack([p, np.ones(len(u)), -np.ones(len(u))])
    sol, _ = nnls(a, np.asarray(x, dtype=float), maxiter=50 * a.shape[1])
    return sol[:-2], sol[-2] - sol[-1]


def predict_static_pi(u: np.ndarray, w: np.ndarray, c: float, thresholds: np.ndarray = THRESHOLDS_V) -> np.ndarray:
    return play_outputs(np.ascontiguousarray(u, dtype=float), np.asarray(thresholds, dtype=float)) @ w + c


def biased_sine(
    frequency_hz: float, cycles: int = CYCLES, fs: float = SAMPLE_RATE_HZ, v_max: float = 120.0
) -> np.ndarray:
    """The paper's 0 → ``v_max`` biased sine (V), ``cycles`` periods at ``fs``."""
    return signals.biased_sine(frequency_hz, cycles, fs, 0.0, v_max).value


def last_cycle(u: np.ndarray, x: np.ndarray, frequency_hz: float, fs: float = SAMPLE_RATE_HZ):
    n = int(round(fs / frequency_hz))
    return u[-n:], x[-n:]


def loop_width(u: np.ndarray, x: np.ndarray, bin_v: float = 1.0) -> float:
    """Max vertical separation of falling and rising branches at the same u (µm), one cycle
    that rises first then falls; branches are averaged in ``bin_v`` bins against noise."""
    half = int(np.argmax(u))
    edges = np.arange(u.min(), u.max() + bin_v, bin_v)
    rise = _binned(u[: half + 1], x[: half + 1], edges)
    fall = _binned(u[half:], x[half:], edges)
    ok = ~np.isnan(rise) & ~np.isnan(fall)
    return float(np.max(fall[ok] - rise[ok]))


def _binned(u, x, edges):
    idx = np.digitize(u, edges) - 1
    sums = np.bincount(idx, weights=x, minlength=len(edges))
    counts = np.bincount(idx, minlength=len(edges))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)[: len(edges) - 1]


def run_loops(
    bench_name: str = "default",
    seed: int = 0,
    frequencies_hz=FREQUENCIES_HZ,
    overrides: dict | None = None,
    axes: tuple[str, ...] = ("y", "z"),
) -> dict:
    """One fresh bench per (frequency, axis), the other axis held at 0 V. Returns
    {axis: {f: (u_cmd, x_um)}}. Each run's seed depends on its frequency and axis only, so one
    axis swept alone (``axes``) gives the same records as both."""
    from drivers.factory import open_bench

    data: dict = {axis: {} for axis in axes}
    for i, f in enumerate(frequencies_hz):
        u = biased_sine(f)
        for j, axis in enumerate(("y", "z")):
            if axis not in axes:
                continue
            bench = open_bench(bench_name, seed=seed + 2 * i + j, overrides=overrides)
            try:
                record = bench.run({axis: u}, SAMPLE_RATE_HZ)
            finally:
                bench.close()
            data[axis][f] = (record.u_cmd_v[axis], record.x_um[axis])
    return data


def measure_calibration(bench_name: str = "default", seed: int = 0, overrides: dict | None = None) -> dict:
    """Strokes, loop widths and static-PI RMS errors per axis (see module docstring)."""
    data = run_loops(bench_name, seed, FREQUENCIES_HZ, overrides)
    result: dict = {
        "bench": bench_name,
        "seed": seed,
        "sample_rate_hz": SAMPLE_RATE_HZ,
        "cycles": CYCLES,
        "frequencies_hz": list(FREQUENCIES_HZ),
        "axes": {},
    }
    for axis, loops in data.items():
        u1, x1 = loops[1.0]
        w, c = fit_static_pi(u1, x1)
        ax: dict = {
            "pi_weights_um_per_v": [float(v) for v in w],
            "pi_offset_um": float(c),
            "pi_weight_sum_um_per_v": float(np.sum(w)),
            "per_frequency": {},
        }
        for f, (u, x) in loops.items():
            uc, xc = last_cycle(u, x, f)
            stroke = float(xc.max() - xc.min())
            w_f, c_f = fit_static_pi(u, x)
            ax["per_frequency"][f] = {
                "stroke_um": stroke,
                "loop_width_um": loop_width(uc, xc),
                "loop_width_pct": 100.0 * loop_width(uc, xc) / stroke,
                "pi_1hz_rms_um": rms(x - predict_static_pi(u, w, c)),
                "pi_refit_rms_um": rms(x - predict_static_pi(u, w_f, c_f)),
            }
        pf = ax["per_frequency"]
        ax.update(
            stroke_um=pf[1.0]["stroke_um"],
            loop_width_pct=pf[1.0]["loop_width_pct"],
            pi_rms_1hz_um=pf[1.0]["pi_1hz_rms_um"],
            pi_rms_100hz_um=pf[100.0]["pi_1hz_rms_um"],
            pi_refit_rms_100hz_um=pf[100.0]["pi_refit_rms_um"],
        )
        result["axes"][axis] = ax
    return result


VARIANTS = ("creep", "dynamics", "delay", "cross_coupling", "asymmetry", "drift", "rate_dependence")


def sweep_pi_rms(bench_name: str, seed: int = 0) -> dict:
    """Static-PI RMS left on a characterisation sweep: each axis driven alone (other at 0 V) at
    1, 10, 50, 100 Hz, 5 cycles, a fresh bench per record; one PI per axis fitted on all eight
    records of that axis (its undriven records included, where coupling shows)."""
    from drivers.factory import open_bench

    records = []
    for i, f in enumerate(FREQUENCIES_HZ):
        u = biased_sine(f)
        for j, driven in enumerate(("y", "z")):
            bench = open_bench(bench_name, seed=seed + 10 * i + j)
            try:
                records.append(bench.run({driven: u}, SAMPLE_RATE_HZ))
            finally:
                bench.close()
    out, sq, n = {}, 0.0, 0
    for axis in ("y", "z"):
        u = [np.ascontiguousarray(r.u_cmd_v[axis]) for r in records]
        p = np.vstack([play_outputs(v, THRESHOLDS_V) for v in u])
        x = np.concatenate([r.x_um[axis] for r in records])
        a = np.column_stack([p, np.ones(len(x)), -np.ones(len(x))])
        sol, _ = nnls(a, x, maxiter=50 * a.shape[1])
        e = x - a @ sol
        out[axis] = rms(e)
        sq, n = sq + float(np.sum(e**2)), n + len(e)
    out["both"] = float(np.sqrt(sq / n))
    return out


def rating_rows(bench_name: str = "default", seed: int = 0) -> list[str]:
    """Markdown rows of the loop to the stacks' 150 V rating: third cycle of a 1 Hz biased sine to 120
    and to 150 V, both axes driven together; min, max, loop width at mid-voltage (descending −
    ascending) and the top slope (fit over the last 20 ms of the rise)."""
    from drivers.factory import open_bench

    rows = []
    for v_max in (120.0, 150.0):
        u = signals.biased_sine(1.0, 3, SAMPLE_RATE_HZ, 0.0, v_max).value
        bench = open_bench(bench_name, seed=seed)
        try:
            record = bench.run({"y": u, "z": u}, SAMPLE_RATE_HZ)
        finally:
            bench.close()
        for axis in ("y", "z"):
            uc, xc = last_cycle(record.u_cmd_v[axis], record.x_um[axis], 1.0)
            top = int(np.argmax(uc))
            mid = v_max / 2
            rising = np.interp(mid, uc[: top + 1], xc[: top + 1])
            falling = np.interp(mid, uc[top:][::-1], xc[top:][::-1])
            last = slice(top - int(0.02 * SAMPLE_RATE_HZ), top + 1)
            slope = np.polyfit(uc[last], xc[last], 1)[0]
            rows.append(
                f"| 0–{v_max:g} V | {axis.upper()} | {xc.min():.3f} | {xc.max():.3f} | "
                f"{falling - rising:.3f} (at {mid:g} V) | {slope:.3f} |"
            )
    return rows


def write_report(path: str | Path = "docs/calibration.md", bench_name: str = "default", seed: int = 0) -> dict:
    """Measure, render docs/img/calibration_loops.png and write the markdown report."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    if not path.is_absolute():
        path = ROOT / path
    img = path.parent / "img" / "calibration_loops.png"
    img.parent.mkdir(parents=True, exist_ok=True)
    from service.reports.calibration_notes import fit_markdown
    from service.reports.reproduction import reproduce

    res = measure_calibration(bench_name, seed)
    res["variants"] = {name: sweep_pi_rms(name, seed) for name in ("base",) + VARIANTS}
    res["fit_markdown"] = fit_markdown(
        {axis: v["rms_um"] for axis, v in reproduce(bench_name, seed, with_pso=False).items()},
        res["axes"]["z"]["per_frequency"][100.0]["stroke_um"],
        bench_name,
    )
    res["rating_rows"] = rating_rows(bench_name, seed)
    data = run_loops(bench_name, seed)
    fig, axs = plt.subplots(1, 2, figsize=(11, 4.6))
    for k, axis in enumerate(("y", "z")):
        for f in FREQUENCIES_HZ:
            u, x = last_cycle(*data[axis][f], f)
            axs[k].plot(u, x, lw=1.0, label=f"{f:g} Hz")
        axs[k].set_title(f"{axis.upper()} axis, last of {CYCLES} cycles ({bench_name} bench)")
        axs[k].set_xlabel("actuator voltage u (V)")
        axs[k].set_ylabel("displacement x (µm)")
        axs[k].grid(alpha=0.3)
        axs[k].legend()
    fig.tight_layout()
    fig.savefig(img, dpi=110)
    plt.close(fig)
    from service.reports.doc_sections import kept_section  # calibration_measured writes its own section

    kept = kept_section(path, "paper_measured calibration")
    path.write_text(_markdown(res, img.relative_to(path.parent)) + (f"\n{kept}" if kept else ""))
    return res


def _markdown(res: dict, img: Path) -> str:
    """docs/calibration.md from the calibration's results ``res`` and its figure ``img``."""
    lines = _summary_lines(res) + _per_frequency_lines(res)
    lines += ["", f"![hysteresis loops at 1, 10, 50 and 100 Hz]({img.as_posix()})", "", NOTES]
    if "fit_markdown" in res:
        lines += ["", res["fit_markdown"]]
    if "rating_rows" in res:
        lines += _rating_lines(res)
    if "variants" in res:
        lines += _variant_lines(res)
    return "\n".join(lines) + "\n"


def _summary_lines(res: dict) -> list[str]:
    """The drive, the method and the table of stroke, loop width and static-PI figures against the paper."""
    lines = [
        "# Calibration of the emulated bench against the paper",
        "",
        f"Produced by `python -m service.reports.calibration` (bench `{res['bench']}`, seed {res['seed']}). "
        f"Drive: u = 60 − 60 cos(2πft) V from 0 V, {res['cycles']} cycles at {res['sample_rate_hz']:g} Hz "
        "through `Bench.run`, one axis at a time with the other at 0 V (as in the paper), a fresh bench per run. "
        "Stroke and loop width are measured on the last cycle; the loop width is the largest vertical "
        "separation of the falling and rising branches at the same u (1 V bins), divided by the stroke. "
        "Static PI: 10 play operators, thresholds 0, 6, …, 54 V, weights ≥ 0 by NNLS plus a free offset, "
        "fitted on the whole 1 Hz record (all cycles).",
        "",
        "| quantity | Y emulator | Y paper | Z emulator | Z paper |",
        "|---|---|---|---|---|",
    ]
    y, z = res["axes"]["y"], res["axes"]["z"]
    rows = [
        ("stroke at 1 Hz (µm)", "stroke_um", "stroke_um", "{:.2f}"),
        ("loop width at 1 Hz (% of stroke)", "loop_width_pct", None, "{:.1f}"),
        ("static PI RMS, 1 Hz fit on 1 Hz (µm)", "pi_rms_1hz_um", "pi_rms_1hz_um", "{:.4f}"),
        ("static PI RMS, 1 Hz fit on 100 Hz (µm)", "pi_rms_100hz_um", "pi_rms_100hz_um", "{:.4f}"),
        ("static PI RMS, refitted on 100 Hz (µm)", "pi_refit_rms_100hz_um", "pi_rms_100hz_um", "{:.4f}"),
        ("PI weight sum (µm/V)", "pi_weight_sum_um_per_v", None, "{:.4f}"),
    ]
    paper_sum = {"y": 0.0534, "z": 0.0772}
    for label, key, pkey, fmt in rows:
        py = (
            fmt.format(PAPER["y"][pkey])
            if pkey
            else ("10–15 (target)" if "width" in label else f"{paper_sum['y']:.4f}")
        )
        pz = (
            fmt.format(PAPER["z"][pkey])
            if pkey
            else ("10–15 (target)" if "width" in label else f"{paper_sum['z']:.4f}")
        )
        lines.append(f"| {label} | {fmt.format(y[key])} | {py} | {fmt.format(z[key])} | {pz} |")
    return lines


def _per_frequency_lines(res: dict) -> list[str]:
    """Stroke, loop width and static-PI RMS per axis and frequency."""
    lines = [
        "",
        "Per frequency:",
        "",
        "| axis | f (Hz) | stroke (µm) | loop width (%) | PI (1 Hz fit) RMS (µm) | PI refit RMS (µm) |",
        "|---|---|---|---|---|---|",
    ]
    for axis in ("y", "z"):
        for f, v in res["axes"][axis]["per_frequency"].items():
            lines.append(
                f"| {axis.upper()} | {f:g} | {v['stroke_um']:.3f} | {v['loop_width_pct']:.1f} | "
                f"{v['pi_1hz_rms_um']:.4f} | {v['pi_refit_rms_um']:.4f} |"
            )
    return lines


def _rating_lines(res: dict) -> list[str]:
    """The stack's rating: the loops at its full drive."""
    lines = []
    lines += [
        "",
        RATING,
        "",
        "| drive | axis | min (µm) | max (µm) | loop width at mid-voltage (µm) | top slope (µm/V) |",
        "|---|---|---|---|---|---|",
        *res["rating_rows"],
        "",
        RATING_TEST,
    ]
    return lines


def _variant_lines(res: dict) -> list[str]:
    """The hidden-effect variants' static-PI RMS against base."""
    lines = []
    base = res["variants"]["base"]["both"]
    lines += [
        "",
        "## Hidden-effect variants",
        "",
        "Static-PI RMS left on a characterisation sweep (`sweep_pi_rms`: each axis driven alone at "
        "1, 10, 50, 100 Hz, 5 cycles; one 10-operator PI per axis over all its records). Each variant is "
        "`base` plus one effect; the test suite requires ≥ 2× base.",
        "",
        "| bench | Y RMS (µm) | Z RMS (µm) | both (µm) | × base |",
        "|---|---|---|---|---|",
    ]
    for name, v in res["variants"].items():
        lines.append(f"| {name} | {v['y']:.4f} | {v['z']:.4f} | {v['both']:.4f} | {v['both'] / base:.1f} |")
    lines += [
        "",
        "On `base` the gauge noise is 3 nm rms; the rest of its residual is the mismatch between a "
        "continuous, bias-dependent Preisach density and 10 discrete PI thresholds.",
    ]
    return lines


NOTES = """## Reading the numbers

- The emulator's hysteresis is a Preisach model (continuous density, Everett function), not a PI,
  so a static PI never fits it exactly. At 1 Hz most of the PI error comes from what the paper's
  static PI lacks: the electrostrictive and saturating asymmetry of the loop, creep during the
  5 s record, and thermal/gauge drift.
- Between 1 and 100 Hz the 1 Hz-fitted PI error grows for three physical reasons: part of the
  switched strain relaxes with a time constant of milliseconds (the loop widens and shrinks with
  rate), the AO→AI latency and amplifier/gauge bandwidths add phase, and the flexure's first mode
  amplifies the response. Z's mode (290.7 Hz) sits almost on the third harmonic of a 100 Hz drive
  (300 Hz), so the harmonics the loop puts into the strain ring it; the fitted damping keeps that
  ringing down, and what the mode still costs at 100 Hz is quantified under "Residual disagreements".
- "refitted on 100 Hz" refits the static PI on the 100 Hz record itself. The paper identified its
  static PI on the 1 Hz loop (§2.3.1), and Table 6's static column is read that way (the reproduction's
  static PI is the 1 Hz fit); the refit shows how much of the 100 Hz error is loop shape alone.
"""
RATING = """## The loop to 150 V (the stacks' rating)

The paper identified over 0–120 V; the default bench's hard limit is the PTJ150 stacks' 0–150 V
rating (`[axes.*.piezo] rated_min_v, rated_max_v`). Between 120 and 150 V the emulated stack keeps
behaving physically: the Preisach memory (its grid spans the amplifier's −20…150 V output ± 5 V)
keeps switching, the saturation of the switched strain grows (the slope at the top falls), creep
runs on, and nothing clamps at 120 V. Measured on the default bench (seed 0), third cycle of a 1 Hz
biased sine, Y and Z driven together (`rating_rows`). The loop width is descending − ascending at
mid-voltage; the top slope is the fit over the last 20 ms of the rise:"""
RATING_TEST = """`tests/unit/drivers/test_emulator_bench.py::test_stack_rating_is_the_limit_and_the_stack_moves_on_to_150_v`
checks that 140 V is accepted and 151 V refused, and that a slow ramp's end position rises at every
10 V step from 120 to 150 V on both axes."""


if __name__ == "__main__":  # pragma: no cover
    if "--fit" in sys.argv[1:]:
        from service.reports.calibration_fit import main as fit_main

        sys.exit(fit_main(sys.argv[1:]))
    out = write_report(sys.argv[1] if len(sys.argv) > 1 else "docs/calibration.md")
    for axis, v in out["axes"].items():
        print(
            axis,
            {
                k: round(v[k], 4)
                for k in ("stroke_um", "loop_width_pct", "pi_rms_1hz_um", "pi_rms_100hz_um", "pi_refit_rms_100hz_um")
            },
        )
