"""Stages hiding an effect outside the built-in library (issue 38 §1), built without the product's
code on tests/support/hysteresis_worlds.py's materials and drives, and the measurement of what
`discover` says about them: does its description of what remains lead with the right signature?

Kinds (each a form no built-in effect draws, so the library can at best approximate it):
- ``"gain_relax"``: the stack depolarises and settles, its gain falling 2 % towards a new level
  with a 2 s time constant (x·(1 − 0.02·(1 − e^(−t/2 s))); the library's gain change is linear in t);
- ``"self_heating"``: the gain rises 0.5 % per kelvin of a temperature no thermometer records, heated
  by the drive's rate (a loss ∝ |u̇|, 0.2 K per kV moved) and cooling with a 20 s time constant;
- ``"chirp_line"``: a machine spinning up nearby, a 10 nm line sweeping 30 → 45 Hz over the record
  (the library's line is one fixed frequency);
- ``"two_lines"``: 10 nm of 50 Hz mains and 8 nm at 37.3 Hz from a pump, neither locked to the drive;
- ``"offset_settle"``: the gauge's mount settles thermally, its zero moving 40 nm with a 1 s time
  constant (the library's drift is a polynomial in t).

Each is recorded (5 kHz, 2 nm of gauge noise) on a Prandtl–Ishlinskii material (Maxwell-slip) and a
non-PI one (Bouc–Wen, β < γ), in either of a lab's two record forms (``--forms``):
- ``"long"``: one record, every block one after the other with their rests, the material's state
  carried through; the hidden effect runs on the record's own time;
- ``"blocks"``: one record per block, as a lab cuts one file per block: each from rest at 0 V and its
  own t = 0, the material from its virgin state (tests/support/hysteresis_worlds.material_blocks, as
  the repo's clean stages are), with FILE_GAP_S of unrecorded rest at 0 V between files. Every hidden
  effect runs on the session's clock (since the stage and gauge were powered), which no file carries:
  a stack's depolarisation and a gauge mount's settling follow power-up, not a file's start; the
  unrecorded temperature is a state that cools in the gaps and carries into the next file; a machine's
  sweep and the mains and pump lines keep the wall clock's phase (restarting them with each file would
  lock them to the drive's start, which nothing in a lab does). So the settling kinds sit mostly in the
  first file, and a file's own time is not the time the effect follows.

Run: ``python -m tests.support.open_world [--kinds ...] [--worlds ...] [--seeds 0 1] [--forms blocks long]``
(``--forms`` defaults to ``long``, the form of the first measured table); prints one row per stage and,
per form, the share whose description leads with the right signature (JSON with ``--json``).
Units: µm for displacements, V for drives, s for time, Hz for frequencies.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

import numpy as np

from tests.support.hysteresis_worlds import WORLDS, blocks_v, imported_records, material_blocks

FS_HZ = 5000.0
#: "blocks" form: the unrecorded rest at 0 V between one file and the next (s), a lab saving a file
FILE_GAP_S = 1.0
FORMS = ("long", "blocks")
#: the signature (its name's start) a right description leads with, per kind
EXPECTED = {
    "gain_relax": "gain changing with time",
    "self_heating": "gain changing with time",
    "chirp_line": "line at",
    "two_lines": "line at",
    "offset_settle": "drift with time",
}
#: a disturbance not locked to the drive: no effect that changes the loop's shape may be claimed for it
UNLOCKED = ("chirp_line", "two_lines")
#: effects that only remove what is not the stack's loop (a disturbance, a time trend, capacity)
NOT_LOOP_SHAPE = {"line_disturbance", "drift", "gain_change", "operators", "hysterons", "temperature"}
DEFAULT_WORLDS = ("maxwell_slip", "bw_beta_lt_gamma")


def _self_heating_gain(u_v: np.ndarray, fs: float) -> np.ndarray:
    """1 + 0.005·T, T (K) heated at 2e-4 K per volt moved and cooling with a 20 s time constant."""
    heat = np.abs(np.diff(u_v, prepend=u_v[0])) * 2e-4
    decay, temp, out = np.exp(-1.0 / (20.0 * fs)), 0.0, np.empty(u_v.size)
    for k in range(u_v.size):
        temp = temp * decay + heat[k]
        out[k] = temp
    return 1.0 + 0.005 * out


def hidden_um(kind: str, u_v: np.ndarray, x_um: np.ndarray, fs: float) -> np.ndarray:
    """The gauge's reading (µm, before its noise) of a stage whose loop gives ``x_um``, with ``kind``."""
    t = np.arange(x_um.size) / fs
    if kind == "clean":
        return x_um
    if kind == "gain_relax":
        return x_um * (1.0 - 0.02 * (1.0 - np.exp(-t / 2.0)))
    if kind == "self_heating":
        return x_um * _self_heating_gain(u_v, fs)
    if kind == "chirp_line":
        f0, f1 = 30.0, 45.0
        phase = 2 * np.pi * (f0 * t + 0.5 * (f1 - f0) * t**2 / t[-1])
        return x_um + 0.010 * np.sin(phase + 0.3)
    if kind == "two_lines":
        return x_um + 0.010 * np.sin(2 * np.pi * 50.0 * t + 0.4) + 0.008 * np.sin(2 * np.pi * 37.3 * t + 1.9)
    if kind == "offset_settle":
        return x_um + 0.040 * (1.0 - np.exp(-t / 1.0))
    raise ValueError(f"unknown kind {kind!r}")


def session_files(world: str, kind: str, fs: float = FS_HZ) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(u_v, x_um)] one per block, before the gauge's noise: each block's material output from rest,
    laid on the session's clock with FILE_GAP_S of rest between files, ``kind`` applied on that clock,
    then cut back into files that each start at their own t = 0."""
    gap = int(round(FILE_GAP_S * fs))
    loops = material_blocks(world, fs=fs)
    u_s = np.concatenate([np.concatenate([u, np.zeros(gap)]) for u, _ in loops])
    x_s = np.concatenate([np.concatenate([x, np.full(gap, x[-1])]) for _, x in loops])
    seen = hidden_um(kind, u_s, x_s, fs)
    starts = np.cumsum([0] + [u.size + gap for u, _ in loops[:-1]])
    return [(u, seen[s : s + u.size]) for s, (u, _) in zip(starts, loops)]


def records(world: str, kind: str, noise_um: float = 0.002, seed: int = 0, fs: float = FS_HZ, form: str = "long"):
    """The stage as held-out product Records in ``form`` (module docstring), cut by the product's importer."""
    rng = np.random.default_rng(seed)
    if form == "long":
        u = np.concatenate(blocks_v(fs=fs))
        pairs = [(u, hidden_um(kind, u, WORLDS[world](u, False), fs))]
    elif form == "blocks":
        pairs = session_files(world, kind, fs)
    else:
        raise ValueError(f"unknown form {form!r}")
    noisy = [(u, x + rng.normal(0.0, noise_um, u.size)) for u, x in pairs]
    return imported_records(noisy, fs, f"{world}:{kind}:{form}")


def measure(world: str, kind: str, seed: int, form: str = "long") -> dict:
    """One discover run on the stage: what it added, where it ended, and what its description leads with."""
    from service.science.discovery.loop import discovery_run

    start = time.perf_counter()
    steps = discovery_run(records(world, kind, seed=seed, form=form), continue_past_ambiguity=True)
    last = steps[-1]["diagnosis"]
    remainder = last.get("remainder") or {}
    leading = (remainder.get("signatures") or [{}])[0].get("signature")
    added = steps[-1]["effects"][1:]
    at_floor = bool(last["at_noise_floor"])
    right = leading is not None and leading.startswith(EXPECTED[kind]) if kind in EXPECTED else leading is None
    return {
        "world": world,
        "kind": kind,
        "form": form,
        "seed": seed,
        "added": added,
        "end_to_floor": last["residual_rms_um"] / last["noise_floor_um"],
        "at_noise_floor": at_floor,
        "leading_signature": leading,
        "leading_text": (remainder.get("signatures") or [{}])[0].get("text"),
        "right": bool(right),
        "loop_shape_claimed": sorted(set(_added_as_physics(steps)) - NOT_LOOP_SHAPE) if kind in UNLOCKED else [],
        "seconds": round(time.perf_counter() - start, 1),
    }


def _added_as_physics(steps: list[dict]) -> list[str]:
    """The effects the run added as physics: each one's row in the diagnosis before it was added is of
    kind "physical" (a loop-shape effect on a base that draws any loop shape is offered as capacity)."""
    out = []
    for before, step in zip(steps, steps[1:]):
        if step.get("replaced"):
            continue  # the base's grid swapped at the loop's end: capacity, never physics
        added = step["effects"][-1]
        row = next(c for c in before["diagnosis"]["candidates"] if c["effect"] == added)
        if row["kind"] == "physical":
            out.append(added)
    return out


def summary(rows: list[dict]) -> dict:
    """Stages, those ended at the floor, those described and led by the right signature, and stages of
    an unlocked disturbance given a loop-shape effect."""
    described = [r for r in rows if not r["at_noise_floor"]]
    return {
        "stages": len(rows),
        "ended_at_floor": len(rows) - len(described),
        "described": len(described),
        "leading_right": sum(r["right"] for r in described),
        "loop_shape_claims_for_unlocked": sum(bool(r["loop_shape_claimed"]) for r in rows),
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", nargs="+", default=list(EXPECTED))
    ap.add_argument("--worlds", nargs="+", default=list(DEFAULT_WORLDS))
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--forms", nargs="+", choices=FORMS, default=["long"])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    rows = []
    for form in args.forms:
        for kind in args.kinds:
            for world in args.worlds:
                for seed in args.seeds:
                    row = measure(world, kind, seed, form)
                    rows.append(row)
                    if not args.json:
                        print(
                            f"{form:6s} {kind:14s} {world:18s} s{seed} added={'+'.join(row['added']) or '-':40s} "
                            f"end {row['end_to_floor']:.2f}x floor lead={row['leading_signature']!s:28s} "
                            f"right={row['right']} loop-shape={row['loop_shape_claimed']} ({row['seconds']} s)",
                            flush=True,
                        )
    by_form = {form: summary([r for r in rows if r["form"] == form]) for form in args.forms}
    print(json.dumps({"rows": rows, "summary": by_form}) if args.json else json.dumps(by_form))


if __name__ == "__main__":
    main()
