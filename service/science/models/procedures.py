"""Identification of the paper's models: ``identify(kind, records)``, and the paper's procedures
for the dynamic PI (§2.3): ω from the slowest loop, then α, β.

    model = identify("dynamic_pi", [r1, r10, r50, r100])
    fit_metrics(r100.x_um, model.predict(r100))      # service.science.fitting.metrics

Stage 1 fits a static PI (ω ≥ 0 and the offset) on the 1 Hz loop; stage 2 fits the eight
rate parameters with ω fixed, either exactly (linear least squares) or by the paper's PSO.
``DynamicPI.fit`` instead solves everything jointly, which is the optimum of both.
"""

from __future__ import annotations

import numpy as np

from service.science.data.record import Record, as_record_list
from service.science.fitting.lsq import solve_blocks, stack_blocks
from service.science.fitting.metrics import fit_metrics
from service.science.fitting.pso import PSOResult, pso_minimize
from service.science.models import PAPER_MODELS, HysteresisModel
from service.science.models.base import equal_thresholds
from service.science.models.contract import Drive
from service.science.models.pi import DynamicPI, StaticPI

#: ``identify("dynamic_pi", ..., method=...)``: the joint exact fit or the paper's procedures.
DYNAMIC_METHODS = ("joint", "two_stage", "pso")
RATE_BLOCKS = ("alpha_um_per_v2_s", "beta_um_per_v2_s2")
#: Rows per chunk when scoring all particles (bounds the (rows, particles) temporary).
PSO_CHUNK_ROWS = 16384


def slowest_record(items: list[Record]) -> Record:
    """The record with the longest dominant period (the paper's 1 Hz loop)."""
    return max(items, key=lambda s: s.dominant_period_s)


def rate_problem(data, static_data=None, n_operators: int = 10, fit_offset: bool = True):
    """Stage 1 and the stage-2 regression: (model with ω and offset set; the α and β blocks; target).

    The target is what the static part leaves unexplained over all records of ``data``.
    """
    items = as_record_list(data)
    static_items = [slowest_record(items)] if static_data is None else as_record_list(static_data)
    u_max = max(float(s.u_v.max()) for s in items + static_items)
    static = StaticPI(thresholds_v=equal_thresholds(u_max, n_operators), fit_offset=fit_offset).fit(static_items)
    model = DynamicPI.from_static(static)
    blocks = stack_blocks([[b for b in model.blocks(Drive.of(s)) if b.name in RATE_BLOCKS] for s in items])
    # in the static part's own direction (sign −1: the gauge reads against the drive)
    target = static.sign * np.concatenate([s.require_x() - static.predict(s) for s in items])
    return model, blocks, target


def fit_dynamic_pi_two_stage(data, static_data=None, n_operators: int = 10, fit_offset: bool = True) -> DynamicPI:
    """The paper's split: ω (and offset) on ``static_data`` (default: slowest record), then α, β
    exactly by linear least squares on all records with ω fixed."""
    model, blocks, target = rate_problem(data, static_data, n_operators, fit_offset)
    solution = solve_blocks(blocks, target)
    model.set_parameters(solution.values)
    model.train_rms_um = solution.rms
    return model


def fit_dynamic_pi_pso(
    data,
    static_data=None,
    n_operators: int = 10,
    fit_offset: bool = True,
    n_particles: int = 100,
    n_iterations: int = 100,
    seed: int = 0,
    **pso_options,
) -> tuple[DynamicPI, PSOResult]:
    """The paper's identification: ω from the static fit, then α1..4, β1..4 by PSO (N=100,
    M=100, w=0.5, c1=c2=2) minimising the RMS error over all records (eq. 12).

    Particles start uniform in ±scale_j, scale_j = ‖target‖/‖column_j‖ (the value at which
    parameter j alone would explain the whole residual).
    """
    model, blocks, target = rate_problem(data, static_data, n_operators, fit_offset)
    a = np.hstack([b.columns for b in blocks])
    norms = np.linalg.norm(a, axis=0)
    scale = np.where(norms > 0, np.linalg.norm(target) / np.where(norms > 0, norms, 1.0), 1.0)

    def rms_of_particles(x: np.ndarray) -> np.ndarray:
        sq = np.zeros(x.shape[0])
        for start in range(0, a.shape[0], PSO_CHUNK_ROWS):
            rows = slice(start, start + PSO_CHUNK_ROWS)
            err = target[rows, None] - a[rows] @ x.T  # every particle's prediction: one product
            sq += np.einsum("ij,ij->j", err, err)
        return np.sqrt(sq / a.shape[0])

    result = pso_minimize(
        rms_of_particles, scale, n_particles=n_particles, n_iterations=n_iterations, seed=seed, **pso_options
    )
    model.alpha_um_per_v2_s = result.x[:4].copy()
    model.beta_um_per_v2_s2 = result.x[4:].copy()
    model.train_rms_um = result.cost  # eq. 12 over all records
    return model, result


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
