"""Reproduce the paper's tracking experiment (Fig. 14–15) on the emulated default bench and write
docs/tracking.md with figures docs/img/tracking_*.png.

    python -m service.reports.tracking [--seed 1] [--cycles 50]

Feedforward models are identified on the bench itself from sine sweeps: the paper's static PI on the
0–120 V 1 Hz loop, and a discovery composite model (hysteresis + delay + flexure dynamics) fitted on
1/10/50/100 Hz sweeps over the voltages each case needs; the ILC's learning filter is measured on the
bench with a multisine. A case whose range is beyond the stroke is refused by ``plan``; the report
records the refusal and runs it anyway with ``allow_saturation`` to show what happens.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from drivers.emulated import open_bench
from service.science.control.feedforward import identify, identify_composite_for
from service.science.control.safety import ControlRefused
from service.science.control.session import ILC_PID, PAPER_PID, SCANNED_PID, Controller, track
from service.science.control.stability import delay_margin
from service.science.control.trajectory import Ellipse

ROOT = Path(__file__).resolve().parents[2]
CASES = {"case1": Ellipse((1, 6), (1, 11), 0.0, 100.0, 50), "case2": Ellipse((1, 5), (1, 9), 20.0, 100.0, 50)}
PAPER = {"case1": (0.308, 0.369), "case2": (0.154, 0.252)}
#: the paper's plant per axis: static PI weight sum (µm/V) and FEM first mode (Hz), DESIGN.md §6
PAPER_AXES = {"y": (0.053, 482.6), "z": (0.077, 290.7)}


def controllers(static, composite) -> dict[str, Controller]:
    """The four controllers of issue #6 (a–d) and the variants the findings need (primed rows)."""
    return {"a PID only (tuned)": Controller(pid=SCANNED_PID),
            "b FF only (static PI⁻¹)": Controller(feedforward=static),
            "b' FF only (composite⁻¹)": Controller(feedforward=composite),
            "c FF + PID, paper gains": Controller(feedforward=composite, pid=PAPER_PID),
            "c' FF + PID, tuned gains": Controller(feedforward=composite, pid=SCANNED_PID),
            "c'' FF (static PI⁻¹) + PID, tuned gains": Controller(feedforward=static, pid=SCANNED_PID),
            "d FF + PID + ILC": Controller(feedforward=composite, pid=ILC_PID, ilc=True),
            "d' FF + ILC": Controller(feedforward=composite, ilc=True)}


def run_row(bench, ellipse, ctl) -> tuple[dict, object, object]:
    """One row: ``plan``'s refusal (if any) is kept as ``refused`` and the run goes on with
    ``allow_saturation`` so the table shows what the bench does there."""
    refused = None
    try:
        result, rec, ref = track(bench, ellipse, ctl)
    except ControlRefused as exc:
        refused = exc.reason
        result, rec, ref = track(bench, ellipse, dataclasses.replace(ctl, allow_saturation=True))
    result["refused"] = refused
    return result, rec, ref


def noise_rms_um(bench) -> float:
    """Gauge noise RMS (µm) at rest, both axes (before any motion): 0 V held; white-noise estimate from first
    differences (std(Δx)/√2), which slow creep or drift does not inflate."""
    bench.parts.daq.write_idle()
    rec = bench.run({a: np.zeros(6000) for a in bench.axes}, 20_000.0)   # 0.2 s settle, then 0.1 s measured
    d = np.concatenate([np.diff(rec.x_um[a][4000:]) for a in bench.axes])
    return float(np.std(d) / np.sqrt(2))


def plot(case, name, rec, ref, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    end = (ref.ramp_periods + ref.cycles) * ref.period
    s = slice(end - 2 * ref.period, end)
    fig, ax = plt.subplots(1, 2, figsize=(10, 4.2))
    ax[0].plot(ref.x_um[s, 0], ref.x_um[s, 1], "k-", lw=1.5, label="reference")
    ax[0].plot(rec.x_um[s, 0], rec.x_um[s, 1], "C1--", lw=1, label="actual")
    ax[0].set(xlabel="Y (µm)", ylabel="Z (µm)", title=f"{case}: {name}")
    ax[0].axis("equal")
    ax[0].legend()
    t = np.arange(2 * ref.period) / ref.sample_rate_hz * 1e3
    for i, axis in enumerate("YZ"):
        ax[1].plot(t, (ref.x_um[s, i] - rec.x_um[s, i]) * 1e3, label=f"{axis} error")
    ax[1].set(xlabel="t (ms), last two periods", ylabel="error (nm)")
    ax[1].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cycles", type=int, default=50)
    ap.add_argument("--out", default=str(ROOT / "docs"))
    ap.add_argument("--no-bench", action="store_true", help="skip `evcbench bench control` in the report")
    ap.add_argument("--extra-seeds", type=int, nargs="*", default=[2, 3],
                    help="benches (seeds) on which case 2 (d) is repeated for the spread")
    args = ap.parse_args(argv)
    out = Path(args.out)
    (out / "img").mkdir(parents=True, exist_ok=True)
    for old in (out / "img").glob("tracking_*.png"):
        old.unlink()
    bench = open_bench("default", seed=args.seed)
    noise = noise_rms_um(bench)
    static = {ax: identify(bench, ax, "static_pi") for ax in bench.axes}
    rows, fits = {}, {}
    for case, ell in CASES.items():
        ell = Ellipse(ell.y_range_um, ell.z_range_um, ell.inclination_deg, ell.frequency_hz, args.cycles)
        composite = identify_composite_for(bench, ell)
        fits[case] = {ax: {"fit_range_v": m.fit_range_v, **m.describe()} for ax, m in composite.items()}
        for name, ctl in controllers(static, composite).items():
            t0 = time.perf_counter()
            result, rec, ref = run_row(bench, ell, ctl)
            result["wall_s"] = time.perf_counter() - t0
            rows[(case, name)] = result
            if result["tripped"] is None:
                tag = name.split()[0].replace("'", "p")
                plot(case, name, rec, ref, out / "img" / f"tracking_{case}_{tag}.png")
            print(case, name, json.dumps({k: v for k, v in result.items() if k != "error_per_period_um"},
                                         default=str), flush=True)
    seeds = seed_spread(args.extra_seeds, args.cycles)
    bench.close()
    bench_json = None
    if not args.no_bench:
        from service.perf.control import run_control_benchmark
        bench_json = run_control_benchmark()
    write_markdown(out / "tracking.md", rows, noise, args, bench_json, fits, seeds)
    return {"noise_rms_um": noise, "rows": {f"{c} | {n}": r for (c, n), r in rows.items()}, "seeds": seeds}


def seed_spread(seeds, cycles: int) -> dict:
    """Case 2 (d) on other emulated benches (seeds): fresh models, same procedure; relative % and RMS µm."""
    out = {}
    for seed in seeds:
        b = open_bench("default", seed=seed)
        noise = noise_rms_um(b)
        ell = dataclasses.replace(CASES["case2"], cycles=cycles)
        composite = identify_composite_for(b, ell)
        result, _, _ = track(b, ell, Controller(feedforward=composite, pid=ILC_PID, ilc=True))
        b.close()
        out[seed] = {"noise_rms_um": noise, "relative_error_pct": result.get("relative_error_pct"),
                     "rms_error_um": result.get("rms_error_um"), "tripped": result["tripped"]}
        print("seed", seed, out[seed], flush=True)
    return out


def _fmt(r, key, scale=1.0, digits=3):
    v = r.get(key)
    return "—" if v is None else f"{v * scale:.{digits}f}"


def write_markdown(path: Path, rows: dict, noise: float, args, bench_json: dict | None = None,
                   fits: dict | None = None, seeds: dict | None = None) -> None:
    lines = [
        "# Trajectory tracking at 100 Hz (paper §4, Fig. 14–15) on the emulated default bench", "",
        "Regenerate (≈3 min on one core; writes this file and docs/img/tracking_*.png):", "",
        "    .venv/bin/python -m service.reports.tracking "
        f"--seed {args.seed} --cycles {args.cycles} --extra-seeds {' '.join(map(str, args.extra_seeds))}", "",
        "Point-by-point at 20 kHz through the compiled loop: the same `track()` path as "
        "`POST /api/trajectories` and `evcbench bench control`.", "",
        "**Feedforward.** *static PI⁻¹*: the paper's static PI (10 operators, thresholds 0–54 V) fitted on "
        "the bench's 0–120 V 1 Hz loop, inverted exactly. *composite⁻¹* "
        "(`CompositeModel.inverse`, `service/science/discovery/composite_inverse.py`): a discovery composite model, hysteresis + delay + flexure "
        "dynamics (`service/science/discovery/composite.py`, harmonic search for the resonance), fitted on "
        "1/10/50/100 Hz sine sweeps over the voltage span the case needs (±5 V; found from a first 0–120 V "
        "fit): the transforms are inverted per harmonic of the reference, then the PI by the exact "
        "numerical inverse. **PID**: paper eq. 19 with filtered derivative and anti-windup. **ILC**: "
        "harmonic ILC on harmonics 1–20 of 100 Hz, learning filter γ/Ĝ(k): Ĝ measured on the bench "
        "by a multisine in the same loop, then refined from the run's own ΔE/ΔU; γ = 0.2, γ/4 on harmonics "
        "at the noise. Errors are over the last 5 of the steady periods.", "",
        f"Gauge noise at rest (measured): {noise * 1e3:.2f} nm RMS → the (d) RMS target is "
        f"{2 * noise * 1e3:.1f} nm.", ""]
    if fits:
        for case, per in fits.items():
            lines.append(f"- composite models for {case}: " + "; ".join(
                f"{ax.upper()} fitted on {v['fit_range_v'][0]:.1f}–{v['fit_range_v'][1]:.1f} V, "
                f"{v.get('dynamics', '')}, {v.get('delay', '')}" for ax, v in per.items()))
        lines.append("")
    lines += ["| case | controller | max error Y (µm) | max error Z (µm) | RMS (nm) | relative error (%) | note |",
              "|---|---|---|---|---|---|---|"]
    for case, (py, pz) in PAPER.items():
        lines.append(f"| {case} | **paper** (FF + PID) | {py} | {pz} | — | < 6.2 | Fig. 15 |")
        for (c, name), r in rows.items():
            if c != case:
                continue
            note = r["tripped"] or (r.get("ilc_stop_reason") or "")
            if r.get("refused"):
                note = "refused by default (beyond the stroke), run with allow_saturation. " + note
            elif r.get("warnings"):
                note = "warned: beyond the stroke by the hysteresis-only model. " + note
            if r.get("command_at_limit_pct"):
                note = f"command at 0/120 V {r['command_at_limit_pct']:.1f} % of samples. " + note
            lines.append(f"| {case} | {name} | {_fmt(r, 'max_error_y_um')} | {_fmt(r, 'max_error_z_um')} | "
                         f"{_fmt(r, 'rms_error_um', 1e3, 1)} | {_fmt(r, 'relative_error_pct', 1, 2)} | {note} |")
    lines += ["", "Relative error = max over axes of max|error| / reference peak-to-peak (paper: 0.308/5 µm = 6.2 %).",
              "", "## Targets (issue #6)", ""]
    for case in PAPER:
        c = rows.get((case, "c' FF + PID, tuned gains"), {})
        d = rows.get((case, "d FF + PID + ILC"), {})
        if c.get("relative_error_pct") is not None:
            ok = "met" if c["relative_error_pct"] <= 3 else "**not met**"
            lines.append(f"- {case} (c) relative ≤ 3 % (tuned gains; the paper's gains trip): "
                         f"{c['relative_error_pct']:.2f} % — {ok}")
        if d.get("relative_error_pct") is not None:
            ok = "met" if d["relative_error_pct"] <= 0.5 and d["rms_error_um"] <= 2 * noise else "**not met**"
            lines.append(f"- {case} (d) relative ≤ 0.5 % and RMS ≤ 2× noise ({2 * noise * 1e3:.1f} nm) within "
                         f"{args.cycles} periods: {d['relative_error_pct']:.2f} %, {d['rms_error_um'] * 1e3:.1f} nm — {ok}")
    refusal = rows.get(("case1", "b' FF only (composite⁻¹)"), {}).get("refused")
    if refusal:
        lines += ["", "Case 1 is refused by `plan` (and `POST /api/trajectories`, 422 on `z_range_um`) with:", "",
                  f"> {refusal}"]
    if seeds:
        lines += ["", "## Spread over benches (case 2, d FF + PID + ILC, fresh models per bench)", "",
                  "| seed | relative error (%) | RMS (nm) | 2× noise (nm) |", "|---|---|---|---|"]
        d = rows.get(("case2", "d FF + PID + ILC"), {})
        if d.get("relative_error_pct") is not None:
            lines.append(f"| {args.seed} | {d['relative_error_pct']:.2f} | {d['rms_error_um'] * 1e3:.1f} | "
                         f"{2 * noise * 1e3:.1f} |")
        for seed, r in seeds.items():
            lines.append(f"| {seed} | {_fmt(r, 'relative_error_pct', 1, 2)} | {_fmt(r, 'rms_error_um', 1e3, 1)} | "
                         f"{2 * r['noise_rms_um'] * 1e3:.1f} |")
    lines += ["", "## Why the paper's gains trip: delay margins (`service/science/control/stability.py`)", "",
              "PID per eq. 19 (e in µm, u in V, t in s) around each axis modelled on the paper's own numbers: "
              "the static PI weight sum (Y 0.053, Z 0.077 µm/V), the FEM first mode (Y 482.6, Z 290.7 Hz) and "
              "an assumed damping ratio of 0.05. A loop sampled at 20 kHz has at least 75 µs of delay (one "
              "sample of latency plus half a sample of hold); the paper's USB DAQ in a LabVIEW loop has ~1 ms.", "",
              "| gains | axis | crossover (Hz) | phase margin without delay (°) | delay margin (µs) |", "|---|---|---|---|---|"]
    for label, gains in (("paper", PAPER_PID), ("tuned (rows c')", SCANNED_PID)):
        for axis, (g, fn) in PAPER_AXES.items():
            m = delay_margin(gains[axis].kp, gains[axis].ki, gains[axis].kd, g, fn, 0.05)
            lines.append(f"| {label} | {axis.upper()} | {m.crossover_hz:.0f} | {m.phase_margin_deg:.1f} | "
                         f"{m.delay_margin_s * 1e6:.0f} |")
    lines += ["", "The paper's gains cross over at 3–5 kHz, where the derivative term carries the loop, and stand "
              "52 µs (Y) and 74 µs (Z) of delay: less than any 20 kHz loop has, and far less than the paper's "
              "own hardware. Read in these units they cannot have been stable on the paper's bench either, so "
              "the paper's eq. 19 must have used other units or scaling than it states; rows (c) run them "
              "as stated, and the divergence watch takes the output to 0 V.",
              "", "## Figures (last two steady periods: reference vs actual, and the error)", ""]
    for p in sorted((path.parent / "img").glob("tracking_*.png")):
        lines.append(f"![{p.stem}](img/{p.name})")
    lines += ["", "## Error per period while ILC learns (nm RMS, every 5th period)", ""]
    for (c, name), r in rows.items():
        if "ILC" in name and r["error_per_period_um"]:
            e = np.asarray(r["error_per_period_um"]) * 1e3
            lines.append(f"- {c}, {name}: " + ", ".join(f"{v:.1f}" for v in e[::5]))
    if bench_json is not None:
        lines += ["", "## Benchmark (`evcbench bench control --json`, same run)", "", "```json",
                  json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in bench_json.items()},
                             indent=1), "```", "",
                  "The machine is shared (2 cores, several sessions): the wall-clock real-time factor varies "
                  "with the neighbours' load (best of 3 runs is reported, all three listed); "
                  "`closed_loop_cpu_realtime_factor` divides by the process's own CPU time instead. The "
                  "loop's floor is the emulator's per-sample physics and noise generation (~0.6 µs/sample); "
                  "the controller itself (PID + amortised compiled ILC step) is `controller_us_per_sample`."]
    path.write_text("\n".join(lines) + "\n" + NOTES)


NOTES = """
## How it runs

- `service/science/control/trajectory.py`: the ellipse (range or amplitude form, inclination of the long axis to Z)
  with raised-cosine start/stop ramps of 3 periods on centre and amplitude.
- `service/science/control/feedforward.py`, `service/science/discovery/composite_inverse.py`: inverse-model feedforward from a
  static PI or a discovery composite model (stored composite model ids work as `feedforward_model_y/z`).
- `service/science/control/kernels.py`: numba PID (eq. 19, filtered derivative, conditional-integration
  anti-windup, integral bounded by the voltage span), the clamp to 0–120 V and to the slew/current step,
  the divergence watch, and the compiled point-by-point runner built once per plant step function.
- `service/science/control/loop.py`: period-by-period orchestration — point-by-point runs each period in the
  compiled runner; buffered streams one period per block with two blocks queued (a correction first
  reaches the period two after the one it learned from); fault check at every period; 0 V at every end.
- `service/science/control/ilc.py`: harmonic ILC with a zero-phase ideal Q (harmonics 1–20) and learning gain
  γ/Ĝ(k). Ĝ starts from a multisine response measured on the bench in the same loop and is refined
  from the run itself (ΔE ≈ −G·ΔU between the corrections actually applied, blended with the measured
  prior), because the piezo's incremental gain depends on the amplitude. Harmonics whose error is at
  the measured noise learn at γ/4, so the correction averages noise out. The learned command is
  projected into 0–120 V; a monitor watches the learnable error (harmonics 0–20), pauses learning when
  it stops falling (resuming if the error rises 1.25×) and reverts with half the gain on divergence.
- `service/science/control/safety.py`: mode, current, slew, resonance, gauge-range and stroke refusals with reasons.
- Over REST: `POST /api/sweeps` (with `v_min`/`v_max` to cover the span a trajectory needs), `POST /api/models`
  with `"effects": ["hysteresis", "delay", "dynamics"]` per axis, then `POST /api/trajectories` with
  `controller.feedforward_model_y/z` set to those model ids. A range beyond the stroke gets 422 on
  `y_range_um`/`z_range_um` with the reason; `controller.allow_saturation: true` runs it clamped and
  returns the reason in `result.warnings`.

## Findings

- **The paper's PID gains are unstable on this emulator** (rows c; see the delay margins above: they
  need less loop delay than a 20 kHz loop has): the divergence watch trips within 15 ms and the output
  goes to 0 V. The (c) target is judged on rows c', the same FF + PID with gains found by a short scan on the
  emulator (kp 1 V/µm, ki 300 V/(µm·s), kd 0.01 V·s/µm, tf 0.2 ms; the derivative damps the Z mode).
  Under ILC the PID is gentler (kp 0.5, ki 300, kd 0.005): it damps the modes and rejects drift while the
  ILC does the tracking.
- **The composite feedforward is what brings (c) under 3 % on case 2.** With the paper's static PI⁻¹
  (row c'') FF + PID stays near 6.7 %: at 100 Hz the Z command's 3rd harmonic (300 Hz) sits on the 290 Hz
  mode, and a loop stable against that mode has too little gain there. The composite model inverts the
  mode per harmonic, and fitting it on the voltage span the ellipse uses captures the stack's minor loops
  (Preisach memory), which a PI fitted on the 0–120 V loop mispredicts. Tried and dropped as feedforward
  effects: asymmetry, creep and rate dependence (2.2 %, 4.2 %, 11.9 % on case 2 c' against 2.1 % without
  them — fitted on sine sweeps, their columns extrapolate badly to the ellipse).
- **Case 1 is beyond the Z stroke, a physical limit of the emulated bench, not a controller failure.**
  The stack alone reaches ≈10.0 µm at 120 V (measured 1 Hz 0–120 V loop: 0.69–10.00 µm; the models say
  10.03–10.12 µm). After the stack comes the flexure (290 Hz mode), which amplifies the 100 Hz fundamental
  by ≈13 %: for the output to be exactly 1–11 µm the stack must deliver the reference through the inverse
  of that mode, 10.41 µm at its peak — more than it has. (Measured: a full 0–120 V 100 Hz sine gives a mean
  of 5.39 µm and a fundamental of 5.30 µm — 10.70 µm together, short of 11 µm — plus a 1.1 µm 3rd
  harmonic from the mode.) So every controller leaves ≈0.6 µm at the top of Z (rows d, d': 6–8 %) and the
  command sits at 120 V for several % of the samples. `plan` and the API refuse this range with the numbers
  (quoted above) instead of running it and failing quietly; the emulator's physics were not changed.
- Results vary by a few tenths of a percent with the seed and the bench's history (hysteresis memory,
  creep); case 2 (d) sits near the 0.5 % line on some benches (spread table).
"""

if __name__ == "__main__":
    main()
