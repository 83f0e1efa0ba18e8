"""Identification, public entry: separable bounded least squares over design blocks, the
paper's two-stage and PSO procedures for the dynamic PI, and fit metrics.

    model = identify("dynamic_pi", [r1, r10, r50, r100])
    fit_metrics(r100.x_um, model.predict(r100))

Implementation lives in ``service.science.fitting``; this module is the stable surface.
"""

from __future__ import annotations

from service.science.data.record import Record, as_record_list
from service.science.fitting.dynamic import (
    fit_dynamic_pi_pso,
    fit_dynamic_pi_two_stage,
    rate_problem,
    slowest_record,
)
from service.science.fitting.lsq import (
    Block,
    LsqSolution,
    SeparableSolution,
    design_matrix,
    separable_least_squares,
    solve_blocks,
    stack_blocks,
)
from service.science.fitting.metrics import fit_metrics
from service.science.fitting.pso import PSOResult, pso_minimize
from service.science.models import PAPER_MODELS, HysteresisModel

#: ``identify("dynamic_pi", ..., method=...)``: the joint exact fit or the paper's procedures.
DYNAMIC_METHODS = ("joint", "two_stage", "pso")


def identify(model_name: str, data: Record | list[Record], method: str = "joint", **options) -> HysteresisModel:
    """Fit the registered model ``model_name`` to ``data`` (one Record or several, jointly).

    ``options`` go to the model's constructor (``n_operators``, ``thresholds_v``,
    ``fit_offset``); for ``dynamic_pi`` with ``method="two_stage"|"pso"`` they go to the
    procedure (``static_data``, ``n_operators``, ``fit_offset``, PSO settings).
    """
    if model_name not in PAPER_MODELS:
        raise ValueError(f"unknown model {model_name!r}; known: {', '.join(PAPER_MODELS)}")
    if method != "joint":
        if model_name != "dynamic_pi" or method not in DYNAMIC_METHODS:
            raise ValueError(
                f"method {method!r} is not available for {model_name!r}; "
                f"dynamic_pi takes one of {', '.join(DYNAMIC_METHODS)}, other models 'joint'"
            )
        if method == "two_stage":
            return fit_dynamic_pi_two_stage(data, **options)
        return fit_dynamic_pi_pso(data, **options)[0]
    return PAPER_MODELS[model_name](**options).fit(data)


def evaluate(model: HysteresisModel, data: Record | list[Record]) -> list[dict]:
    """``fit_metrics`` of ``model`` on each record, labelled."""
    return [{"label": s.label, **fit_metrics(s.require_x(), model.predict(s))} for s in as_record_list(data)]


__all__ = [
    "Block",
    "LsqSolution",
    "SeparableSolution",
    "PSOResult",
    "DYNAMIC_METHODS",
    "design_matrix",
    "solve_blocks",
    "stack_blocks",
    "separable_least_squares",
    "pso_minimize",
    "fit_dynamic_pi_two_stage",
    "fit_dynamic_pi_pso",
    "rate_problem",
    "slowest_record",
    "fit_metrics",
    "evaluate",
    "identify",
]
