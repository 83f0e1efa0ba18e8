"""Issue 37's matrix on the stages of tests/support/hysteresis_worlds.py: what discovery's loop ends
with, against the noise floor, on held-out cycles.

    .venv/bin/python -m tests.support.world_matrix [--worlds bw_n2 preisach_gauss] [--forms blocks long cut]
        [--noise-nm 2] [--stroke-scale 0.1] [--bipolar] [--json out.json]
    .venv/bin/python -m tests.support.world_matrix --base-only [--n-operators 5] [--fs 5000] ...


Per stage: the held-out RMS of the first step (hysteresis alone) and of the model the loop ends
with (``service.science.discovery.loop.discovery_run``, as the discover job decides on imported records:
this bench cannot run another stage's experiments, so at an ambiguity it adds the leading claim and goes
on, and the ambiguity is still reported), the noise floor
the diagnosis measures, the effects the loop added and the time it took.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

from tests.support.hysteresis_worlds import FORMS, HIDDEN, WORLDS, records


def run_stage(
    world: str,
    form: str,
    noise_nm: float = 2.0,
    seed: int = 0,
    bipolar: bool = False,
    hidden: str | None = None,
    stroke_scale: float = 1.0,
) -> dict:
    """One stage through the discovery loop: figures in nm, effects added, seconds."""
    from service.science.discovery.loop import discovery_run

    recs = records(world, form, noise_nm * 1e-3, seed, bipolar=bipolar, hidden=hidden, stroke_scale=stroke_scale)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        steps = discovery_run(recs, continue_past_ambiguity=True)
    first, last = steps[0]["diagnosis"], steps[-1]["diagnosis"]
    floor = last["noise_floor_um"] * 1e3
    return {
        "world": world,
        "form": form,
        "bipolar": bipolar,
        "hidden": hidden,
        "noise_nm": noise_nm,
        "stroke_scale": stroke_scale,
        "first_nm": first["residual_rms_um"] * 1e3,
        "end_nm": last["residual_rms_um"] * 1e3,
        "floor_nm": floor,
        "first_ratio": first["residual_rms_um"] * 1e3 / floor,
        "end_ratio": last["residual_rms_um"] * 1e3 / floor,
        "effects": steps[-1]["effects"],
        "claimed_first": [c["effect"] for c in first["candidates"] if c["kind"] == "physical" and c["claimed"]],
        "named_first": next((c["effect"] for c in first["candidates"] if c["kind"] == "physical"), None),
        "seconds": time.perf_counter() - t0,
    }


def base_stage(world: str, form: str, noise_nm: float, n_operators: int, fs: float, bipolar: bool = False) -> dict:
    """The ``hysterons`` base alone (``n_operators`` × its factor of play widths) fitted to the stage,
    no loop: held-out RMS and the noise floor it leaves (nm)."""
    from service.science.discovery.hysteron_model import HysteronModel
    from service.science.discovery.noise import noise_floor

    recs = records(world, form, noise_nm * 1e-3, fs=fs, bipolar=bipolar)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = HysteronModel(n_operators=n_operators).fit(recs)
        held = model.evaluate(recs)["validation_rms_um"] * 1e3
        floor = noise_floor(recs, [r.x_um - model.predict(r) for r in recs])["noise_floor_um"] * 1e3
    return {"world": world, "form": form, "widths": len(model.thresholds_v), "held_out_nm": held, "floor_nm": floor}


def markdown(rows: list[dict]) -> str:
    out = [
        "| stage | hidden | record | drive | first step (nm) | loop's end (nm) | noise floor (nm) | end × floor "
        "| effects the loop added |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        out.append(
            f"| {r['world']} | {r['hidden'] or 'none'} | {r['form']} | {'±' if r['bipolar'] else '0…'}120 V | {r['first_nm']:.1f} | "
            f"{r['end_nm']:.2f} | {r['floor_nm']:.2f} | {r['end_ratio']:.2f} | {', '.join(r['effects'][1:]) or 'none'} |"
        )
    return "\n".join(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--worlds", nargs="*", default=list(WORLDS))
    ap.add_argument("--forms", nargs="*", default=["blocks", "long"], choices=list(FORMS))
    ap.add_argument("--noise-nm", type=float, default=2.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--bipolar", action="store_true")
    ap.add_argument("--hidden", choices=HIDDEN, help="one physical effect behind the material")
    ap.add_argument("--stroke-scale", type=float, default=1.0, help="the stage's motion × this (same noise)")
    ap.add_argument("--json")
    ap.add_argument("--base-only", action="store_true", help="fit the hysterons base alone, no loop")
    ap.add_argument("--n-operators", type=int, default=10, help="with --base-only: the PI's play operators")
    ap.add_argument("--fs", type=float, default=20000.0, help="with --base-only: sample rate (Hz)")
    args = ap.parse_args(argv)
    if args.base_only:
        for world in args.worlds:
            for form in args.forms:
                r = base_stage(world, form, args.noise_nm, args.n_operators, args.fs, args.bipolar)
                print(
                    f"{world:26s} {form:6s} {r['widths']} widths: held out {r['held_out_nm']:.2f} nm, "
                    f"floor {r['floor_nm']:.2f} nm ({r['held_out_nm'] / r['floor_nm']:.2f}x)",
                    flush=True,
                )
        return
    rows = []
    for world in args.worlds:
        for form in args.forms:
            rows.append(run_stage(world, form, args.noise_nm, args.seed, args.bipolar, args.hidden, args.stroke_scale))
            r = rows[-1]
            print(
                f"{world:18s} {form:6s} first {r['first_nm']:7.2f} end {r['end_nm']:7.2f} floor {r['floor_nm']:5.2f} "
                f"({r['end_ratio']:.2f}x) {r['effects']} claimed@0 {r['claimed_first']} {r['seconds']:.1f}s",
                flush=True,
            )
    print(markdown(rows))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
