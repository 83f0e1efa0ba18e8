"""Reproduce the paper's tracking experiment (Fig. 14–15) on the emulated default bench and write
docs/tracking.md with figures docs/img/tracking_*.png.

    python -m service.control.report [--seed 1] [--cycles 50]

Feedforward models are identified on the bench itself from 0–120 V sine sweeps (static PI on the
1 Hz loop; dynamic PI on 1/10/50/100 Hz for comparison); the ILC's learning filter is measured on the
bench with a multisine.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from drivers.emulated import open_bench
from service.control.feedforward import identify
from service.control.session import ILC_PID, PAPER_PID, TUNED_PID, Controller, track
from service.control.trajectory import Ellipse

ROOT = Path(__file__).resolve().parents[2]
CASES = {"case1": Ellipse((1, 6), (1, 11), 0.0, 100.0, 50), "case2": Ellipse((1, 5), (1, 9), 20.0, 100.0, 50)}
PAPER = {"case1": (0.308, 0.369), "case2": (0.154, 0.252)}


def controllers(models, dynamic) -> dict[str, Controller]:
    return {"a PID only (tuned)": Controller(pid=TUNED_PID),
            "b FF only (static PI⁻¹)": Controller(feedforward=models),
            "b' FF only (dynamic PI⁻¹)": Controller(feedforward=dynamic),
            "c FF + PID, paper gains": Controller(feedforward=models, pid=PAPER_PID),
            "c' FF + PID, tuned gains": Controller(feedforward=models, pid=TUNED_PID),
            "d FF + PID + ILC": Controller(feedforward=models, pid=ILC_PID, ilc=True),
            "d' FF + ILC": Controller(feedforward=models, ilc=True)}


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
    args = ap.parse_args(argv)
    out = Path(args.out)
    (out / "img").mkdir(parents=True, exist_ok=True)
    bench = open_bench("default", seed=args.seed)
    noise = noise_rms_um(bench)
    models = {ax: identify(bench, ax, "static_pi") for ax in bench.axes}
    dynamic = {ax: identify(bench, ax, "dynamic_pi") for ax in bench.axes}
    rows = {}
    for case, ell in CASES.items():
        ell = Ellipse(ell.y_range_um, ell.z_range_um, ell.inclination_deg, ell.frequency_hz, args.cycles)
        for name, ctl in controllers(models, dynamic).items():
            t0 = time.perf_counter()
            result, rec, ref = track(bench, ell, ctl)
            result["wall_s"] = time.perf_counter() - t0
            rows[(case, name)] = result
            if result["tripped"] is None:
                tag = name.split()[0].replace("'", "p")
                plot(case, name, rec, ref, out / "img" / f"tracking_{case}_{tag}.png")
            print(case, name, json.dumps({k: v for k, v in result.items() if k != "error_per_period_um"},
                                         default=str), flush=True)
    bench.close()
    bench_json = None
    if not args.no_bench:
        from service.benchmarks.control import run_control_benchmark
        bench_json = run_control_benchmark()
    write_markdown(out / "tracking.md", rows, noise, args, bench_json)
    return {"noise_rms_um": noise, "rows": {f"{c} | {n}": r for (c, n), r in rows.items()}}


def _fmt(r, key, scale=1.0, digits=3):
    v = r.get(key)
    return "—" if v is None else f"{v * scale:.{digits}f}"


def write_markdown(path: Path, rows: dict, noise: float, args, bench_json: dict | None = None) -> None:
    lines = [
        "# Trajectory tracking at 100 Hz (paper §4, Fig. 14–15) on the emulated default bench", "",
        f"Produced by `python -m service.control.report --seed {args.seed} --cycles {args.cycles}` "
        "(point-by-point at 20 kHz through the compiled loop; the same path as `POST /api/trajectories` "
        "and `evcbench bench control`).", "",
        "Feedforward: static PI per axis (10 operators, 0–54 V thresholds) identified on the bench from the "
        "0–120 V 1 Hz sweep; row b' uses a dynamic PI fitted on 1/10/50/100 Hz sweeps (no emulator internals): "
        "the 50/100 Hz loops carry the flexure's ringing, which the dynamic PI absorbs into its rate terms, "
        "so its inverse is worse at 100 Hz on this bench. ILC: harmonic ILC on harmonics 1–20 of 100 Hz (zero-phase Q: harmonics "
        "above 20 are not learned), learning filter γ/G(k) with G measured on the bench by a 10 V multisine "
        "in the same loop, γ = 0.2. Errors are over the last 5 of the steady periods.", "",
        f"Gauge noise at rest (measured): {noise * 1e3:.2f} nm RMS → the (d) RMS target is "
        f"{2 * noise * 1e3:.1f} nm.", "",
        "| case | controller | max error Y (µm) | max error Z (µm) | RMS (nm) | relative error (%) | note |",
        "|---|---|---|---|---|---|---|"]
    for case, (py, pz) in PAPER.items():
        lines.append(f"| {case} | **paper** (FF + PID) | {py} | {pz} | — | < 6.2 | Fig. 15 |")
        for (c, name), r in rows.items():
            if c != case:
                continue
            note = r["tripped"] or (r.get("ilc_stop_reason") or "")
            if r.get("command_at_limit_pct"):
                note = f"command at 0/120 V {r['command_at_limit_pct']:.1f} % of samples. " + note
            lines.append(f"| {case} | {name} | {_fmt(r, 'max_error_y_um')} | {_fmt(r, 'max_error_z_um')} | "
                         f"{_fmt(r, 'rms_error_um', 1e3, 1)} | {_fmt(r, 'relative_error_pct', 1, 2)} | {note} |")
    lines += ["", "## Targets (issue #6)", ""]
    for case in PAPER:
        c = rows.get((case, "c' FF + PID, tuned gains"), {})
        d = rows.get((case, "d FF + PID + ILC"), {})
        if c.get("relative_error_pct") is not None:
            ok = "met" if c["relative_error_pct"] <= 3 else "**not met**"
            lines.append(f"- {case} (c) relative ≤ 3 %: {c['relative_error_pct']:.2f} % — {ok}")
        if d.get("relative_error_pct") is not None:
            ok = "met" if d["relative_error_pct"] <= 0.5 and d["rms_error_um"] <= 2 * noise else "**not met**"
            lines.append(f"- {case} (d) relative ≤ 0.5 % and RMS ≤ 2× noise ({2 * noise * 1e3:.1f} nm) within "
                         f"{args.cycles} periods: {d['relative_error_pct']:.2f} %, {d['rms_error_um'] * 1e3:.1f} nm — {ok}")
    lines += ["", "Relative error = max over axes of max|error| / reference peak-to-peak (paper: 0.308/5 µm = 6.2 %).",
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
                  "The machine is shared during CI: the real-time factor varies with load (30–60× seen); the "
                  "loop's floor is the emulator's own per-sample physics (~0.6 µs/sample)."]
    path.write_text("\n".join(lines) + "\n" + NOTES)


NOTES = """
## How it runs

- `service/control/trajectory.py`: the ellipse (range or amplitude form, inclination of the long axis to Z)
  with raised-cosine start/stop ramps of 3 periods on centre and amplitude.
- `service/control/kernels.py`: numba PID (eq. 19, filtered derivative, conditional-integration
  anti-windup, integral bounded by the voltage span), the clamp to 0–120 V and to the slew/current step,
  the divergence watch (|error| > p-p + 0.5 µm for 10 samples, or the gauge at 98 % of its range), and the
  compiled point-by-point runner built once per plant step function.
- `drivers/emulated/devices.py`: `EmulatedDaq.stepping_hook()` (additive) hands a compiled caller the
  emulator's own per-sample kernel, its state arrays and its noise stream; a DAQ without it (or with
  `point_by_point=False`, e.g. a USB DAQ) gets point-by-point refused with the reason.
- `service/control/loop.py`: period-by-period orchestration — point-by-point runs each period in the
  compiled runner; buffered streams one period per block with two blocks queued (a correction first
  reaches the period two after the one it learned from); fault check (amplifier, gauge) at every period;
  0 V at every end.
- `service/control/ilc.py`: harmonic ILC with a zero-phase ideal Q (harmonics 1–20), learning gain
  γ/G(k) from a multisine response measured on the bench in the same loop, projection of the learned
  command into 0–120 V, and a monitor that pauses learning when the error stops falling (resuming if it
  rises 1.25×) and reverts with half the gain on divergence.
- `evcbench bench control --json`: controller µs per sample, margin at 20 kHz, closed-loop real-time
  factor — measured on the same `track()` path the API job runs.

## Findings

- **The paper's PID gains are unstable on this bench** (kp 50/70 V/µm × ≈0.09 µm/V ≈ loop gain 4–6 against
  lightly damped 291 Hz (Z) / 483 Hz (Y) flexure modes plus one-sample latency and the amplifier and gauge
  lags): the divergence watch trips within 15 ms and the output goes to 0 V (rows c). Rows c' use gains found
  by a short scan on the emulator (kp 1 V/µm, ki 300 V/(µm·s), kd 0.01 V·s/µm, tf 0.2 ms); the derivative
  term damps the Z mode.
- **FF + PID stays at 6.7–7.3 %** (paper: < 6.2 %; target (c) ≤ 3 % not met). At 100 Hz, Z's 3rd harmonic
  (300 Hz) sits on its 290.7 Hz resonance; the residual harmonics of the hysteresis inverse ring the flexure,
  and a loop stable against that mode has too little gain at 300 Hz to cancel them. The ILC, which learns
  through the plant, removes them: case 2 (d) reaches ≈0.5 % and ≈5 nm RMS (gauge noise ≈3 nm).
- **Static PI beats dynamic PI as the feedforward here**: the 50/100 Hz sweep loops include the flexure's
  dynamic response, which the dynamic PI's rate terms absorb; its inverse then mis-predicts at 100 Hz (b').
- **Case 1's Z range (1–11 µm) is at the edge of the emulated Z stack's reach** at 0–120 V (quasi-static
  sweep: 0.7–10.0 µm): the command sits at 0 or 120 V for 7–9 % of the samples (note column), which bounds
  what any controller can do there; the ILC projects its correction into 0–120 V so it cannot wind up.
  Case 2 (Z 1–9 µm) is inside the reach.
- Results vary by a few tenths of a percent with the seed and the bench's history (hysteresis memory,
  creep); case 2 (d) sits near the 0.5 % line (0.3–0.6 % seen).
"""


if __name__ == "__main__":
    main()
