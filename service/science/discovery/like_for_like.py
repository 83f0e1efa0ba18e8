"""Every step of a discovery scored on the same data (issue 37 §3).

When an experiment adds a dataset, the steps after it are fitted and scored on more data, and often
harder data (faster rates, the other axis driven): their held-out RMS is not comparable with the
steps before, and a history read step by step rose where the model had got better. Here each step's
effects are refitted on the enlarged records — their transforms (a delay, a mode) kept as the step
found them, the weights fitted again exactly on the training cycles — and scored on the same held-out
cycles as every other step: ``like_for_like_rms_um``. Beside it, ``original_data_rms_um``: that same
like-for-like fit scored on the held-out cycles of the records the run started from (not the step's own
fit, which had fewer records: the two differ on the same data). Pure science: no store.
"""

from __future__ import annotations

from service.science.discovery.column_memo import shared_effect_columns
from service.science.discovery.composite import CompositeModel
from service.science.discovery.rests import LineFree
from service.science.fitting.validation import evaluate_records


def effects_key(effects) -> tuple[str, ...]:
    """One key per effect set, whatever the order the steps list them in."""
    return tuple(sorted(e for e in effects if e != "hysteresis"))


@shared_effect_columns()  # the steps' refits share each effect's columns of the same records
def like_for_like(
    line_free: LineFree,
    n_original: int,
    steps: list[tuple[list[str], dict]],
    n_operators: int = 10,
    fitted: dict | None = None,
) -> list[dict]:
    """Per step ``(effects, theta)`` (its effects beyond hysteresis, its transform parameters):
    ``{"like_for_like_rms_um", "original_data_rms_um"}``, the held-out RMS (µm, mean over blocks) of
    those effects fitted on ``line_free``'s records (judged as the steps' diagnoses judged them) with the transforms kept, over every record and over the first
    ``n_original`` (the data the run started from). ``fitted``: models already fitted on these
    records, by ``effects_key`` (the steps since the data last grew), scored as they are. A step whose
    effect set another shares gets the same figures."""
    done = {}
    fitted = fitted or {}
    records = line_free.records
    for effects, theta in steps:
        key = effects_key(effects)
        if key in done:
            continue
        model = fitted.get(key) or CompositeModel(list(key), n_operators, fixed_theta=theta).fit(records)
        preds = [model.predict(r) for r in records]
        done[key] = {
            "like_for_like_rms_um": evaluate_records(records, preds)["validation_rms_um"],
            "original_data_rms_um": evaluate_records(records[:n_original], preds[:n_original])["validation_rms_um"],
        }
    return [dict(done[effects_key(effects)]) for effects, _ in steps]
