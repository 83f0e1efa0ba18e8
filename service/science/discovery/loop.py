"""One full discovery run as a report: diagnose, add the top physical candidate, refit, repeat
until the verdict is complete, then more hysteresis capacity while the model is not at the noise
floor and a capacity candidate removes a significant share of the excess; the error history as a figure (matplotlib Agg).

The decisions are ``discovery_step`` (fit and diagnose one step), ``next_effect`` (what the loop adds
next, or None when it stops), ``needed_experiment`` (the sweep it needs before going on) and
``stops_at_ambiguity`` (whether it stops there rather than guess between look-alikes): the
report (``discovery_run``) and the discover job (service.usecases.discover_run) both call them."""

from __future__ import annotations

import json

from service.science.discovery.base_capacity import capacity_before_physics
from service.science.discovery.column_memo import shared_effect_columns
from service.science.discovery.composite import CompositeModel, fit_composite
from service.science.discovery.diagnosis import diagnose, helpful_capacity

MAX_STEPS = 8


@shared_effect_columns()  # the step's fit and its diagnosis share each effect's columns
def discovery_step(
    records, effects, n_operators: int = 10, theta: dict | None = None, model: CompositeModel | None = None
) -> tuple[CompositeModel, dict]:
    """Fit ``hysteresis + effects`` (warm at ``theta``; or take the fitted ``model`` as it is) and
    diagnose it: ``(model, {"effects", "diagnosis", "per_block"})``, per-block validation RMS and
    noise floor in µm."""
    model = model if model is not None else fit_composite(records, effects, n_operators, theta)
    d = diagnose(records, model=model)
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


def next_effect(d: dict) -> str | None:
    """The effect the loop adds after diagnosis ``d``: the top claimed physical candidate while the
    verdict is missing_effect; then capacity while it is validated and the model is not at the noise
    floor; None when the loop stops."""
    first = capacity_before_physics(d)  # the base cannot draw the loop: it grows first (issue 37)
    if first is not None:
        return first["effect"]
    if d["verdict"] == "missing_effect":
        return next(c["effect"] for c in d["candidates"] if c["kind"] == "physical" and c["claimed"])
    # complete as far as physics goes: more capacity if the model is not at the noise floor yet
    capacity = helpful_capacity(d["candidates"], d["residual_rms_um"])  # only effects not in the model
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
    if amb and json.dumps(amb["experiment"], sort_keys=True) not in ran:
        return {"effects": list(amb["effects"]), "reason": amb["text"], "experiment": amb["experiment"]}
    if not stopping or d["at_noise_floor"]:
        return None
    for c in d.get("not_testable", []):
        if c["kind"] == "physical" and json.dumps(c["experiment"], sort_keys=True) not in ran:
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


def discovery_run(
    records, n_operators: int = 10, max_steps: int = MAX_STEPS, continue_past_ambiguity: bool = False
) -> list[dict]:
    """Steps of an automatic discovery: each with effects, diagnosis and per-block validation RMS. It
    stops at an ambiguity (the last step's diagnosis names the separating sweep) unless
    ``continue_past_ambiguity``, as the discover job does without experiments."""
    effects, steps, theta = [], [], {}
    for _ in range(max_steps):
        model, step = discovery_step(records, effects, n_operators, theta)
        theta = model.theta
        steps.append(step)
        added = next_effect(step["diagnosis"])
        if added is None or stops_at_ambiguity(step["diagnosis"], continue_past_ambiguity):
            break
        effects = effects + [added]
    return steps


def history_figure(steps: list[dict], path: str, title: str = "") -> None:
    """Held-out RMS per step (mean over blocks) with the noise floor, log scale, to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = ["hysteresis"] + ["+" + s["effects"][-1] for s in steps[1:]]
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
        for f in d["failures"][:3]:
            out.append(f"- fails worst at: {f['text']}")
        for c in d["candidates"][:3]:
            out.append(
                f"- candidate `{c['effect']}` ({c['kind']}), score {c['score']:.2f}, expected "
                f"{c['expected_rms_um'] * 1e3:.2f} nm: {c['evidence']}"
            )
        if d.get("ambiguity"):
            out.append(f"- ambiguity: {d['ambiguity']['text']}; experiment: `{d['ambiguity']['experiment']}`")
        out.append("")
    return "\n".join(out)
