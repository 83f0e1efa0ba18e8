"""The discover job's result as the API, the dashboard and the CLI read it: each step's summary and
its line of progress, the run's answer (also its partial result while it runs), and which fit a step's
figures are of. Figures in µm, as stored."""

from __future__ import annotations

from service.render.text import step_change
from service.science.data.units import fmt_nm
from service.science.discovery.parameters import parameter_units, physical_parameters


def step_summary(index: int, model_id: str, step: dict, run: dict, joined: str | None) -> dict:
    """One step as the result shows it (µm); ``joined``: the experiment's dataset new in its fit."""
    d = step["diagnosis"]
    previous = run["steps"][-1] if run["steps"] else None
    added = [e for e in step["effects"] if previous and e not in previous["effects"]]
    replaced = [e for e in previous["effects"] if e not in step["effects"]] if previous else []
    return {
        "step": index,
        "model_id": model_id,
        "parent_id": previous["model_id"] if previous else None,
        "effects": step["effects"],
        "added": added[0] if added else None,
        # the effect ``added`` took the place of (the base's grid swapped at the loop's end), else None
        "replaced": replaced[0] if replaced else None,
        "experiment_dataset_id": joined,
        "not_kept": [],
        "validation_rms_um": d["residual_rms_um"],
        "train_rms_um": d["train_rms_um"],
        "noise_floor_um": d["noise_floor_um"],
        "ratio_to_noise_floor": _ratio(d["residual_rms_um"], d["noise_floor_um"]),
        "at_noise_floor": d["at_noise_floor"],
        "verdict": d["verdict"],
        "verdict_text": d["verdict_text"],
        "answer_text": d["answer"]["text"],
        "ambiguous": d["ambiguity"]["effects"] if d.get("ambiguity") else None,
        "per_block": [
            {**b, "ratio_to_noise_floor": _ratio(b["validation_rms_um"], b["noise_floor_um"])}
            for b in step["per_block"]
        ],
        "not_testable": [
            {"effect": c["effect"], "reason": c["reason"], "experiment": c["experiment"]} for c in d["not_testable"]
        ],
    }


def step_words(step: dict) -> str:
    change = step_change(step) or ("refit with the experiment" if step["step"] else "start")
    return (
        f"step {step['step']} ({change}): model {step['model_id']}, held-out RMS "
        f"{fmt_nm(step['validation_rms_um'])}, noise floor {fmt_nm(step['noise_floor_um'])}"
    )


def _ratio(value_um: float | None, floor_um: float | None) -> float | None:
    return value_um / floor_um if value_um is not None and floor_um else None


def discover_result(run: dict, needed: dict | None, stopped: str, reason: str | None, final_model) -> dict:
    """The job's answer (also its partial result while it runs)."""
    steps = run["steps"]
    last = steps[-1] if steps else None
    parameters = physical_parameters(final_model) if final_model is not None else {}
    found = [
        {
            "effect": name,
            # the role it was added in: a loop-shape effect on a base that draws any loop shape is
            # capacity there (loop_shape.loop_shape_as_capacity), never reported as physics
            "kind": c["kind"],
            "added_at_step": index,
            "parameters": parameters.get(name, {}),
            "units": parameter_units(name, parameters.get(name, {})),
            "evidence": c["evidence"],
            "p_value": c["p_value"],
            "score": c["score"],
            "expected_rms_um": c["expected_rms_um"],
        }
        for name, (index, c) in run["added"].items()
        if index < len(steps)
    ]
    remains = (
        None
        if last is None
        else {
            k: last[k]
            for k in (
                "validation_rms_um",
                "noise_floor_um",
                "ratio_to_noise_floor",
                "at_noise_floor",
                "verdict",
                "verdict_text",
                "answer_text",
                "per_block",
                "not_testable",
            )
        }
    )
    return {
        "start_model_id": run["start_model_id"],
        "axis": run["axis"],
        "final_model_id": last["model_id"] if last else None,
        "effects": last["effects"] if last else None,
        "final_parameters": parameters,
        "steps": list(steps),
        "effects_found": found,
        "remains": remains,
        "stopped": stopped,
        "stop_reason": reason,
        "needed_experiment": needed,
        "experiments": list(run["experiments"]),
        "suggested_experiments": list(run["suggested"]),
        "not_kept": list(run["not_kept"]),
        "original_datasets": list(run["original_datasets"]),
        "like_for_like_datasets": list(run.get("like_for_like_datasets") or run["original_datasets"]),
    }


def fit_label(index: int, stands_in: dict | None, effects: list[str]) -> str:
    """Which fit a step's figures are of. Step 0 of a paper's model (static/dynamic PI, GRPI) is the
    composite fitted on the same data standing for it, whose held-out RMS differs from the one the
    model's own page shows (the stored model's): both are named."""
    if index == 0 and stands_in is not None:
        return (
            f"the composite {' + '.join(effects)} fitted on the same data, standing for this {stands_in['kind']} "
            f"(the {stands_in['kind']}'s own held-out RMS, on its page: {fmt_nm(stands_in['validation_rms_um'], 4)})"
        )
    return "the start model as stored" if index == 0 else "this step's stored model"


def stop_without_experiment(d: dict, need: dict, add: str | None, why: str, go_on: bool) -> tuple[str, str] | None:
    """(stopped, reason) when the loop stops for an experiment it does not run, or None when it goes
    on (``go_on``: continue_past_ambiguity, or the bench cannot run it — with the leading claimed
    effect, the step and the result naming the sweep that would tell the pair apart)."""
    if add is None:  # done as far as the data goes; the experiment would test more
        return natural_stop(d), f"{d['answer']['text']} An experiment would test {', '.join(need['effects'])}: {why}"
    if go_on:
        return None
    # ``need`` is the ambiguity (stops_at_ambiguity's answer)
    return "needs_experiment", (
        f"{need['reason']}. Adding either would be a guess the data cannot back, so the loop "
        f"stops here: {why}, or with continue_past_ambiguity to add {add} (the leading "
        f"claim) and go on"
    )


def guess_words(needed: dict | None) -> str:
    """At a natural stop after the loop went on past an ambiguity (``needed``: its experiment, not run),
    that a step rests on a guess and what settles it ("" otherwise): a walk read "Nothing is missing"
    above "The experiment it needs" with nothing joining the two."""
    if not needed or len(needed["effects"]) != 2:
        return ""
    added, other = needed["effects"]
    return (
        f" One step rests on a guess: {added} was added where the data could not tell it from {other}; "
        "the experiment below settles which of the two the stage has."
    )


def natural_stop(d: dict) -> str:
    """Why the loop stops when there is nothing left to add: at the noise floor, or complete."""
    return "at_noise_floor" if d["at_noise_floor"] else "complete"
