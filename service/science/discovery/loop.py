"""One full discovery run as a report: diagnose, add the top physical candidate, refit, repeat
until the verdict is complete, then more hysteresis capacity while the model is not at the noise
floor and a capacity candidate removes a significant share of the excess; the error history as a figure (matplotlib Agg).

The decisions are ``discovery_step`` (fit and diagnose one step), ``try_step`` (fit an added
effect, and keep it only if the held-out RMS on the same data does not rise: ``not_kept``),
``next_effect`` (what the loop adds next, or None when it stops), ``needed_experiment`` (the sweep
it needs before going on), ``stops_at_ambiguity`` (whether it stops there rather than guess between
look-alikes) and ``still_separates`` (whether an experiment cut to the bench's limits still does what
it was asked for): the report (``discovery_run``) and the discover job
(service.usecases.discover_run) both call them."""

from __future__ import annotations

import json

from service.science.data.units import fmt_nm
from service.science.discovery.base_capacity import capacity_before_physics, parsimonious
from service.science.discovery.column_memo import shared_effect_columns
from service.science.discovery.composite import CompositeModel, fit_composite
from service.science.discovery.diagnosis import diagnose_line_free
from service.science.discovery.identifiability import fastest_drive_hz
from service.science.discovery.rests import LineFree
from service.science.discovery.verdict import helpful_capacity
from service.science.effects import EFFECTS
from service.science.fitting.validation import evaluate_records

#: model steps a discovery takes at most (the start and each effect tried): the default bench's Y
#: needs 11 (seven physical effects and the base's capacity) after its experiments
MAX_STEPS = 12
#: the most a request may ask for
MAX_STEPS_ALLOWED = 16


@shared_effect_columns()  # the step's fit and its diagnosis share each effect's columns
def discovery_step(
    line_free: LineFree,
    effects,
    n_operators: int = 10,
    theta: dict | None = None,
    model: CompositeModel | None = None,
) -> tuple[CompositeModel, dict]:
    """Fit ``hysteresis + effects`` on ``line_free``'s records (warm at ``theta``; or take ``model``,
    fitted on them, as it is) and diagnose it: ``(model, {"effects", "diagnosis", "per_block"})``,
    per-block validation RMS and noise floor in µm."""
    model = model if model is not None else fit_composite(line_free.records, effects, n_operators, theta)
    d = diagnose_line_free(line_free, model)
    per_block = [
        {
            "dataset_id": ds["dataset_id"],
            "frequency_hz": b["frequency_hz"],
            "validation_rms_um": b["validation"]["rms_um"],
        }
        for ds in d["metrics"]["per_dataset"]
        for b in ds["blocks"]
    ]
    noise_by_block = [b["noise_um"] for b in d["noise"]["per_block"]]
    for row, nf in zip(per_block, noise_by_block):
        row["noise_floor_um"] = nf
    return model, {"effects": ["hysteresis"] + list(effects), "diagnosis": d, "per_block": per_block}


def held_out_rms_um(records, model: CompositeModel) -> float:
    """The fitted ``model``'s held-out RMS on ``records`` (µm, mean over blocks): the figure its
    diagnosis calls ``residual_rms_um``."""
    return evaluate_records(records, [model.predict(r) for r in records])["validation_rms_um"]


def not_kept(effect: str, before_um: float, after_um: float) -> dict | None:
    """None when adding ``effect`` left the held-out RMS on the same data at most ``before_um``;
    else why it is not kept: ``{"effect", "before_rms_um", "held_out_rms_um", "text"}`` (µm)."""
    if after_um <= before_um:
        return None
    return {
        "effect": effect,
        "before_rms_um": before_um,
        "held_out_rms_um": after_um,
        "text": f"adding {effect} raised the held-out RMS from {fmt_nm(before_um)} to {fmt_nm(after_um)}: not kept",
    }


@shared_effect_columns()
def try_step(
    line_free: LineFree,
    effects,
    added: str,
    n_operators: int,
    theta: dict,
    before_um: float,
    model: CompositeModel | None = None,
) -> tuple[CompositeModel, dict | None, dict | None]:
    """Fit ``hysteresis + effects`` (``added`` the effect new in them, warm at ``theta``) on the
    line-free records the step before was diagnosed on (held-out RMS ``before_um``): ``(model, step,
    None)`` with the step diagnosed as ``discovery_step`` does, or ``(model, None, not_kept(...))``
    when the added effect raised the held-out RMS — then nothing is diagnosed and the loop goes back
    to the step before. ``model``: that fit, made already (``refitted_choice``)."""
    model = model if model is not None else fit_composite(line_free.records, effects, n_operators, theta)
    rejected = not_kept(added, before_um, held_out_rms_um(line_free.records, model))
    if rejected is not None:
        return model, None, rejected
    model, step = discovery_step(line_free, effects, n_operators, model=model)
    return model, step, None


@shared_effect_columns()
def refitted_choice(
    line_free: LineFree, effects, added: str, n_operators: int, theta: dict, d: dict
) -> tuple[str, CompositeModel | None]:
    """The grid of the base the loop adds when diagnosis ``d`` names ``added``, a grid with
    alternatives (``Effect.alternative_to``): each alternative ``d`` claimed, refitted with
    ``effects`` (the model's) as the step will be, chosen by ``parsimonious`` on those held-out
    figures. The diagnosis's own figures for them are its candidates' quick fits; refitted, the
    transforms move with the grid: on a Krasnosel'skii–Pokrovskii stage with a hidden delay, one
    file per block, they read 8.73 nm for ``hysterons`` and 6.88 nm for ``hysterons_fine`` (the
    coarser kept by parsimony, and the loop ended at 2.4× the floor), refitted 5.47 and 2.49 nm.
    Returns the grid and its fitted model (the step takes it as it is); any other effect is
    ``(added, None)``."""
    rows = [
        c
        for c in d["candidates"]
        if c.get("claimed") and (c["effect"] == added or c["effect"] in EFFECTS[added].alternative_to)
    ]
    if len(rows) < 2:
        return added, None
    refitted, models = [], {}
    for row in rows:
        models[row["effect"]] = fit_composite(line_free.records, [*effects, row["effect"]], n_operators, theta)
        refitted.append({**row, "expected_rms_um": held_out_rms_um(line_free.records, models[row["effect"]])})
    chosen = parsimonious(refitted, d["noise_floor_um"] or 0.0)["effect"]
    return chosen, models[chosen]


def swappable_grid(effects, d: dict) -> str | None:
    """The grid of the base in ``effects`` that ``grid_swap`` would compare with its alternatives
    (an effect with ``Effect.alternative_to``), or None: there is none, or diagnosis ``d`` is at the
    noise floor already."""
    grid = next((e for e in effects if EFFECTS[e].alternative_to), None)
    return None if grid is None or d["at_noise_floor"] else grid


@shared_effect_columns()
def grid_swap(line_free: LineFree, effects, n_operators: int, d: dict, model: CompositeModel) -> dict | None:
    """When the loop stops short of the noise floor with a grid of the base in the model (an effect
    with ``Effect.alternative_to``): each alternative grid refitted in its place, every other effect
    kept (warm at the model's theta), and chosen by ``parsimonious`` on the held-out figures, the
    model's own (diagnosis ``d``) among them. The grid was chosen when it was added, beside the
    effects of that step; those added since can change which grid the record asks for (a
    Krasnosel'skii–Pokrovskii stage with a hidden slew limit, one file per block: the loop kept
    ``hysterons`` and ended at 2.77× the floor; with the fine grid in its place, 2.06×).
    ``{"replaced", "effect", "model", "held_out_rms_um", "evidence"}`` (µm) when another grid wins;
    None when the model's own is kept or there is nothing to compare (``swappable_grid``)."""
    grid = swappable_grid(effects, d)
    if grid is None:
        return None
    rows = [{"effect": grid, "expected_rms_um": d["residual_rms_um"], "added_parameters": model.n_parameters()}]
    fitted = {}
    theta = {name: value for name, value in model.theta.items() if name != grid}
    for other in EFFECTS[grid].alternative_to:
        swapped = [other if e == grid else e for e in effects]
        fitted[other] = fit_composite(line_free.records, swapped, n_operators, theta)
        rms = held_out_rms_um(line_free.records, fitted[other])
        rows.append({"effect": other, "expected_rms_um": rms, "added_parameters": fitted[other].n_parameters()})
    chosen = parsimonious(rows, d["noise_floor_um"] or 0.0)
    if chosen["effect"] == grid:
        return None
    return {
        "replaced": grid,
        "effect": chosen["effect"],
        "model": fitted[chosen["effect"]],
        "held_out_rms_um": chosen["expected_rms_um"],
        "evidence": (
            f"in place of {grid}, with every other effect kept: held out {fmt_nm(chosen['expected_rms_um'])} "
            f"against {fmt_nm(d['residual_rms_um'])}; the base's grid, a model-capacity change, not physics"
        ),
    }


def next_effect(d: dict, exclude=()) -> str | None:
    """The effect the loop adds after diagnosis ``d``: the top claimed physical candidate while the
    verdict is missing_effect; then capacity while it is validated and the model is not at the noise
    floor; None when the loop stops. Effects in ``exclude`` (tried on this model and not kept) are
    passed over for the next candidate."""
    first = capacity_before_physics(d)  # the base cannot draw the loop: it grows first (issue 37)
    if first is not None and first["effect"] not in exclude:
        return first["effect"]
    if d["verdict"] == "missing_effect":
        claimed = [c["effect"] for c in d["candidates"] if c["kind"] == "physical" and c["claimed"]]
        claimed = [e for e in claimed if e not in exclude]
        if claimed:
            return claimed[0]
    # complete as far as physics goes: more capacity if the model is not at the noise floor yet
    capacity = helpful_capacity(d["candidates"], d["residual_rms_um"], d["noise_floor_um"] or 0.0)  # not in the model
    capacity = [c for c in capacity if c["effect"] not in exclude]
    if d["at_noise_floor"] or not capacity:
        return None
    return capacity[0]["effect"]


def needed_experiment(d: dict, stopping: bool, done=()) -> dict | None:
    """The sweep the loop needs before it can go on (``{"effects", "reason", "experiment"}``, the
    experiment a ready-to-POST /api/sweeps body), or None: the ambiguity's separating sweep when the
    two leading claimed candidates explain the residual alike; when the loop is ``stopping`` short
    of the noise floor, the first sweep that makes a physical effect testable. Experiments in
    ``done`` (bodies already run) are never asked for again."""
    ran = {json.dumps(body, sort_keys=True) for body in done}
    amb = d.get("ambiguity")
    if capacity_before_physics(d) is not None:  # the base grows first; the next step diagnoses again
        return None
    if amb and amb.get("experiment") and json.dumps(amb["experiment"], sort_keys=True) not in ran:
        return {"effects": list(amb["effects"]), "reason": amb["text"], "experiment": amb["experiment"]}
    if not stopping or d["at_noise_floor"]:
        return None
    for c in d.get("not_testable", []):
        # an experiment this bench cannot run (``not_runnable_here``: no body) is said, never asked for
        if c["kind"] == "physical" and c["experiment"] and json.dumps(c["experiment"], sort_keys=True) not in ran:
            return {"effects": [c["effect"]], "reason": c["reason"], "experiment": c["experiment"]}
    return None


def stops_at_ambiguity(d: dict, continue_past_ambiguity: bool, done=()) -> dict | None:
    """The ambiguity the loop stops at after diagnosis ``d`` (``needed_experiment``'s answer), or None:
    two look-alike candidates explain the residual alike, so adding the leading one would be a guess
    the data cannot back. ``continue_past_ambiguity`` adds the leading claimed effect instead and
    goes on (the ambiguity is still reported)."""
    if continue_past_ambiguity or next_effect(d) is None:
        return None
    return needed_experiment(d, stopping=False, done=done)


#: an experiment asked for rates above the data's is cut to the bench's limits; it still separates
#: when its fastest rate is at least this many times the data's fastest (a resonance's f² gain then
#: differs by ≥ 19 % between the two, a delay's phase by as much)
SEPARATING_RATE_RATIO = 1.1


def still_separates(asked: dict, runnable: dict, records) -> str | None:
    """None when ``runnable`` (the /api/sweeps body ``asked`` cut to the bench's limits) still does
    what ``asked`` was for; else why not. A sweep that asked for rates above the data's fastest own
    drive rate must keep one at least SEPARATING_RATE_RATIO × above it; a step sweep must keep two
    different levels; any other keeps its frequencies."""
    if asked.get("waveform") == "step":
        levels = set(runnable.get("levels_v") or [])
        return None if len(levels) >= 2 else "cut to the bench's voltage range, its steps would not change the drive"
    data_fastest = fastest_drive_hz(records) or 0.0
    asked_fastest = max(asked.get("frequencies_hz") or [0.0])
    kept_fastest = max(runnable.get("frequencies_hz") or [0.0])
    if asked_fastest > data_fastest and kept_fastest < SEPARATING_RATE_RATIO * data_fastest:
        return (
            f"it needs rates above the data's {data_fastest:g} Hz, and the bench allows at most "
            f"{kept_fastest:g} Hz (less than {SEPARATING_RATE_RATIO:g} × {data_fastest:g} Hz)"
        )
    return None if kept_fastest > 0 or asked.get("waveform") != "sine" else "no frequency is left"


def discovery_run(
    records, n_operators: int = 10, max_steps: int = MAX_STEPS, continue_past_ambiguity: bool = False
) -> list[dict]:
    """Steps of an automatic discovery: each with effects, diagnosis, per-block validation RMS and
    ``not_kept`` (effects tried on it that raised the held-out RMS: the loop went back to it and took
    the next candidate). At most ``max_steps`` fits, the ones not kept included. It stops at an
    ambiguity (the last step's diagnosis names the separating sweep) unless
    ``continue_past_ambiguity``, as the discover job does without experiments."""
    line_free = LineFree.of(records)  # every step is fitted and judged without the rests' lines
    model, step = discovery_step(line_free, [], n_operators, {})
    steps, theta, excluded, swapped = [{**step, "not_kept": []}], model.theta, [], False
    added = _next_or_stop(step["diagnosis"], excluded, continue_past_ambiguity)
    for _ in range(max_steps - 1):
        if added is None and not swapped:
            swapped = True  # once a run: the grids are compared with every effect the loop found
            swap = grid_swap(line_free, steps[-1]["effects"][1:], n_operators, steps[-1]["diagnosis"], model)
            if swap is not None:
                effects = [e for e in steps[-1]["effects"][1:] if e != swap["replaced"]] + [swap["effect"]]
                model, step = discovery_step(line_free, effects, n_operators, model=swap["model"])
                steps.append({**step, "not_kept": [], "replaced": swap["replaced"]})
                theta, excluded = model.theta, []
                added = _next_or_stop(step["diagnosis"], excluded, continue_past_ambiguity)
                continue
        if added is None:
            break
        added, fitted = refitted_choice(
            line_free, steps[-1]["effects"][1:], added, n_operators, theta, steps[-1]["diagnosis"]
        )
        effects = steps[-1]["effects"][1:] + [added]
        before = steps[-1]["diagnosis"]["residual_rms_um"]
        fit, step, rejected = try_step(line_free, effects, added, n_operators, theta, before, fitted)
        if rejected is not None:
            steps[-1]["not_kept"].append(rejected)
            excluded.append(added)
            added = next_effect(steps[-1]["diagnosis"], excluded)
            continue
        steps.append({**step, "not_kept": []})
        model = fit  # the last step's model (a fit not kept leaves it as it was)
        theta, excluded = model.theta, []
        added = _next_or_stop(step["diagnosis"], excluded, continue_past_ambiguity)
    return steps


def _next_or_stop(d: dict, excluded, continue_past_ambiguity: bool) -> str | None:
    """The effect the report's loop adds after diagnosis ``d``, None where it stops (an ambiguity)."""
    added = next_effect(d, excluded)
    return None if added is None or stops_at_ambiguity(d, continue_past_ambiguity) else added


def history_figure(steps: list[dict], path: str, title: str = "") -> None:
    """Held-out RMS per step (mean over blocks) with the noise floor, log scale, to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = ["hysteresis"] + [
        f"{s['replaced']}→{s['effects'][-1]}" if s.get("replaced") else "+" + s["effects"][-1] for s in steps[1:]
    ]
    val = [s["diagnosis"]["residual_rms_um"] * 1e3 for s in steps]
    train = [s["diagnosis"]["train_rms_um"] * 1e3 for s in steps]
    noise = [s["diagnosis"]["noise_floor_um"] * 1e3 for s in steps]
    fig, ax = plt.subplots(figsize=(7, 4))
    x = range(len(steps))
    ax.plot(x, val, "o-", label="validation RMS (held-out cycles)")
    ax.plot(x, train, "s--", label="training RMS")
    ax.plot(x, noise, "k:", label="noise floor (non-repeatable part)")
    ax.set_xticks(list(x), labels, rotation=20)
    ax.set_yscale("log")
    ax.set_ylabel("RMS error (nm)")
    ax.set_title(title or "Discovery: error history")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(steps: list[dict]) -> str:
    """The diagnosis at each step in words (for docs/discovery.md)."""
    out = []
    for i, s in enumerate(steps):
        d = s["diagnosis"]
        out.append(f"### Step {i}: {' + '.join(s['effects'])}\n")
        out.append(
            f"- held-out RMS {d['residual_rms_um'] * 1e3:.2f} nm, training {d['train_rms_um'] * 1e3:.2f} nm, "
            f"noise floor {d['noise_floor_um'] * 1e3:.2f} nm, repeatable part "
            f"{(d['repeatable_rms_um'] or 0) * 1e3:.2f} nm"
        )
        out.append(f"- verdict: **{d['verdict']}** — {d['verdict_text']}")
        out.append(f"- answer: {d['answer']['text']}")
        for f in d["failures"][:3]:
            out.append(f"- fails worst at: {f['text']}")
        for c in d["candidates"][:3]:
            out.append(
                f"- candidate `{c['effect']}` ({c['kind']}), score {c['score']:.2f}, expected "
                f"{c['expected_rms_um'] * 1e3:.2f} nm: {c['evidence']}"
            )
        if d.get("ambiguity"):
            out.append(f"- ambiguity: {d['ambiguity']['text']}; experiment: `{d['ambiguity']['experiment']}`")
        for rejected in s.get("not_kept", []):
            out.append(f"- tried next: {rejected['text']}")
        out.append("")
    return "\n".join(out)
