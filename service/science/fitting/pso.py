"""The paper's particle swarm optimiser (§2.3.2, eq. 10–11), vectorised over particles.

Kept to reproduce the paper: the dynamic PI is linear in its parameters, so exact least
squares (``service.science.fitting.lsq``) reaches the optimum it searches for.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass
class PSOResult:
    """Best position, its cost, and the best cost after each iteration."""

    x: np.ndarray
    cost: float
    history: np.ndarray
    n_evaluations: int


def pso_minimize(
    cost: Callable[[np.ndarray], np.ndarray],
    scale,
    center=None,
    n_particles: int = 100,
    n_iterations: int = 100,
    inertia: float = 0.5,
    c1: float = 2.0,
    c2: float = 2.0,
    seed: int = 0,
    v_max_fraction: float | None = 1.0,
) -> PSOResult:
    """Minimise ``cost(X) -> (N,)`` over positions X (N, D) by global-best PSO.

    Particles start at ``center + U[-1, 1] · scale`` with zero velocity (the paper's
    initialisation with a per-parameter scale); velocities are clamped to
    ``v_max_fraction · scale`` per dimension (None: unclamped). Seeded, so reproducible.
    """
    scale = np.asarray(scale, dtype=float)
    dim = scale.size
    center = np.zeros(dim) if center is None else np.asarray(center, dtype=float)
    rng = np.random.default_rng(seed)
    x = center + rng.uniform(-1.0, 1.0, (n_particles, dim)) * scale
    v = np.zeros_like(x)
    v_max = None if v_max_fraction is None else v_max_fraction * scale
    f = np.asarray(cost(x), dtype=float)
    p_best, p_cost = x.copy(), f.copy()
    g = int(np.argmin(p_cost))
    history = np.empty(n_iterations)
    for m in range(n_iterations):
        r1 = rng.random((n_particles, dim))
        r2 = rng.random((n_particles, dim))
        v = inertia * v + c1 * r1 * (p_best - x) + c2 * r2 * (p_best[g] - x)
        if v_max is not None:
            np.clip(v, -v_max, v_max, out=v)
        x = x + v
        f = np.asarray(cost(x), dtype=float)
        better = f < p_cost
        p_best[better], p_cost[better] = x[better], f[better]
        g = int(np.argmin(p_cost))
        history[m] = p_cost[g]
    return PSOResult(p_best[g].copy(), float(p_cost[g]), history, n_particles * (n_iterations + 1))
