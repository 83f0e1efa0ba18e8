"""Tables of the hysteresis families, built once per world with numpy (the kernels read them).

- Preisach: the Everett function of a continuous density (kernels.preisach_update).
- Bouc–Wen: its coefficients from the physical parameters (families.bouc_wen_step).
- Maxwell-slip: the elements' slip limits and weights, drawn from a seeded distribution
  (families.maxwell_slip_step), never the paper's 0, 6, …, 54 V grid.
"""

from __future__ import annotations

import numpy as np


def everett_table(hyst: dict, lo_v: float, step_v: float, n: int, refine: int = 2) -> np.ndarray:
    """Everett function F(alpha_i, beta_j) on an n×n grid for the density
    mu = p(c)·q(b), c = (a-b)/2 (coercive, gamma k=2), b = (a+b)/2 (bias, Gaussian)."""
    h = step_v / refine
    centres = lo_v + (np.arange((n - 1) * refine) + 0.5) * h
    al, be = np.meshgrid(centres, centres, indexing="ij")
    c = 0.5 * (al - be)
    b = 0.5 * (al + be)
    c0 = float(hyst["coercive_mode_v"])
    mu = (c / c0**2) * np.exp(-c / c0) * np.exp(-0.5 * ((b - hyst["bias_center_v"]) / hyst["bias_width_v"]) ** 2)
    mu = np.where(c > 0, mu, 0.0)
    mu[np.diag_indices_from(mu)] *= 0.5  # diagonal cells are half inside the triangle
    mass = mu * h * h
    cum = np.cumsum(mass, axis=0)  # alpha' <= alpha
    cum = np.cumsum(cum[:, ::-1], axis=1)[:, ::-1]  # beta' >= beta
    table = np.zeros((n, n))
    table[1:, : n - 1] = cum[refine - 1 :: refine, ::refine]
    return table


def slip_elements(ms: dict) -> tuple[np.ndarray, np.ndarray]:
    """Maxwell-slip elements drawn from ``distribution_seed``: slip limits (V) log-normal about
    ``threshold_median_v`` (spread ``threshold_log_sigma``, kept within 0.2–80 V), weights from a
    gamma(2) draw scaled to sum to ``slip_fraction`` (the rest of the stack is purely elastic)."""
    rng = np.random.default_rng(int(ms["distribution_seed"]))
    n = int(ms["elements"])
    limits_v = np.clip(ms["threshold_median_v"] * np.exp(ms["threshold_log_sigma"] * rng.standard_normal(n)), 0.2, 80.0)
    weights = rng.gamma(2.0, 1.0, n)
    return limits_v, weights * (ms["slip_fraction"] / weights.sum())


def bouc_wen_coefficients(bw: dict) -> tuple[float, float, float, float, float]:
    """(A, β, γ, n, max_step_v) from the config: β + γ = A / lag_saturation_v^n, so that |h| saturates
    at lag_saturation_v on a long monotone run; γ = gamma_over_beta·β (β, γ in 1/V^n)."""
    gain, n_exp, ratio = bw["hysteretic_gain"], bw["exponent"], bw["gamma_over_beta"]
    beta = gain / (bw["lag_saturation_v"] ** n_exp * (1.0 + ratio))
    return gain, beta, ratio * beta, n_exp, bw["max_step_v"]
