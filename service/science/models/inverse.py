"""Inverse hysteresis: the analytic inverse PI (eq. 14–17) and an exact per-sample
numerical inverse for every model of the family (static PI, dynamic PI, GRPI).

Numerical inverse: with the operator states and (u̇, ü) fixed for the sample, the
model output is piecewise linear in u with known breakpoints, so the root is found
exactly by bracketing between breakpoints (no iteration tolerance). Where the output
is not monotone in u (a dynamic weight ω_i + φ < 0) the root closest to the previous
voltage is taken; an unreachable target saturates at the closest reachable output.
"""

from __future__ import annotations

import numpy as np

from drivers.jit import drop_stale_caches, njit
from service.science.data.record import finite_array
from service.science.data.signals import drive_derivatives
from service.science.models import kernels as model_kernels
from service.science.models.kernels import dynamic_weight_shift, gpi_step, play_operators


def analytic_inverse_parameters(thresholds_v, weights_um_per_v) -> tuple[np.ndarray, np.ndarray]:
    """Inverse thresholds r'_i (µm) and weights ŵ_i (V/µm) of eq. 14–16.

    r'_i = Σ_{j≤i} ω_j (r_i − r_j);  ŵ_1 = 1/ω_1,  ŵ_i = −ω_i / (Σ_{j≤i} ω_j · Σ_{j<i} ω_j).
    Valid for ascending thresholds starting at 0, ω_1 > 0 and all partial sums > 0.
    """
    r = np.asarray(thresholds_v, dtype=float)
    w = np.asarray(weights_um_per_v, dtype=float)
    if r.size != w.size or r.size == 0:
        raise ValueError(f"{r.size} thresholds but {w.size} weights")
    if r[0] != 0.0 or np.any(np.diff(r) <= 0):
        raise ValueError("the analytic inverse needs ascending thresholds_v starting at 0")
    if not w[0] > 0:
        raise ValueError(
            f"the analytic inverse needs weights_um_per_v[0] > 0 (got {w[0]:.3g}): the model has a "
            "dead band at every reversal; use the numerical inverse"
        )
    csum = np.cumsum(w)
    if np.any(csum <= 0):
        raise ValueError("the analytic inverse needs every partial sum of weights_um_per_v to be positive")
    r_inv = r * csum - np.cumsum(w * r)
    w_inv = np.empty_like(w)
    w_inv[0] = 1.0 / w[0]
    w_inv[1:] = -w[1:] / (csum[1:] * csum[:-1])
    return r_inv, w_inv


def analytic_pi_inverse(x_ref_um, thresholds_v, weights_um_per_v, offset_um: float = 0.0) -> np.ndarray:
    """Eq. 17 with constant weights: u = Σ ŵ_i P_{r'_i}[x_ref − offset] from relaxed operators (V)."""
    r_inv, w_inv = analytic_inverse_parameters(thresholds_v, weights_um_per_v)
    x = finite_array("x_ref_um", x_ref_um) - offset_um
    return play_operators(x, r_inv) @ w_inv


@njit(cache=True, nogil=True)
def _solve_sample(x_target, a1, c_l, b1, c_r, thresholds, gains, offset, state, u_prev, u_lo, u_hi, pts, vals):
    """The u at which the generalised PI step (states fixed) outputs ``x_target``."""
    n = thresholds.size
    m = 0
    for i in range(n):
        pts[m] = (state[i] + thresholds[i] - c_l) / a1  # lower envelope reaches the state
        pts[m + 1] = (state[i] - thresholds[i] - c_r) / b1  # upper envelope reaches the state
        m += 2
        if a1 != b1:  # envelopes cross
            pts[m] = (c_r + 2.0 * thresholds[i] - c_l) / (a1 - b1)
            m += 1
    for j in range(m):
        pts[j] = min(max(pts[j], u_lo), u_hi)
    if np.isfinite(u_lo):
        pts[m] = u_lo
        m += 1
    if np.isfinite(u_hi):
        pts[m] = u_hi
        m += 1
    p = pts[:m]
    p.sort()
    for j in range(m):
        vals[j] = gpi_step(p[j], a1, c_l, b1, c_r, thresholds, gains, offset, state, False) - x_target
    best, best_dist = np.nan, np.inf
    for j in range(m):
        cand = np.nan
        if vals[j] == 0.0:
            cand = p[j]
        elif j + 1 < m and (vals[j] < 0.0) != (vals[j + 1] < 0.0) and vals[j + 1] != 0.0:
            cand = p[j] + (p[j + 1] - p[j]) * vals[j] / (vals[j] - vals[j + 1])
        if not np.isnan(cand) and abs(cand - u_prev) < best_dist:
            best, best_dist = cand, abs(cand - u_prev)
    # linear rays beyond the outermost breakpoints when unbounded (slope measured over 1 V)
    for side in (-1.0, 1.0):
        if (side < 0 and np.isfinite(u_lo)) or (side > 0 and np.isfinite(u_hi)):
            continue
        end = p[0] if side < 0 else p[m - 1]
        f_end = vals[0] if side < 0 else vals[m - 1]
        f_out = gpi_step(end + side, a1, c_l, b1, c_r, thresholds, gains, offset, state, False) - x_target
        slope = (f_out - f_end) * side
        if slope != 0.0:
            cand = end - f_end / slope
            if (cand - end) * side > 0.0 and abs(cand - u_prev) < best_dist:
                best, best_dist = cand, abs(cand - u_prev)
    if np.isnan(best):  # unreachable: saturate at the closest reachable output
        best = p[np.argmin(np.abs(vals[:m]))]
    return best


@njit(cache=True, nogil=True)
def _invert(x_ref, thresholds, weights, offset, a1, a2, b1, b2, alpha, beta, du, ddu, u_lo, u_hi, state):
    n = x_ref.size
    u = np.empty(n)
    pts = np.empty(3 * thresholds.size + 2)
    vals = np.empty(3 * thresholds.size + 2)
    gains = np.empty(thresholds.size)
    u_prev = 0.0
    for k in range(n):
        phi = dynamic_weight_shift(du[k], ddu[k], alpha, beta)
        for i in range(thresholds.size):
            gains[i] = weights[i] + phi
        c_l, c_r = a2 * abs(du[k]), b2 * abs(du[k])
        uk = _solve_sample(x_ref[k], a1, c_l, b1, c_r, thresholds, gains, offset, state, u_prev, u_lo, u_hi, pts, vals)
        gpi_step(uk, a1, c_l, b1, c_r, thresholds, gains, offset, state, True)
        u[k] = uk
        u_prev = uk
    return u


def numerical_inverse(
    x_ref_um,
    thresholds_v,
    weights_um_per_v,
    offset_um: float = 0.0,
    sample_rate_hz: float | None = None,
    envelope=(1.0, 0.0, 1.0, 0.0),
    alpha_um_per_v2_s=None,
    beta_um_per_v2_s2=None,
    du_v_per_s=None,
    ddu_v_per_s2=None,
    refinements: int = 0,
    u_limits_v=(-np.inf, np.inf),
    y0=None,
) -> np.ndarray:
    """Per-sample exact inverse (V) of the generalised PI with GRPI ``envelope`` (a1, a2, b1, b2)
    and dynamic weights (α, β per segment), from operator states ``y0`` (default relaxed).

    The rate terms need u̇, ü along the answer. They come from ``du_v_per_s``/``ddu_v_per_s2``
    when given (e.g. a commanded waveform); otherwise from the reference's timing: the
    inverse with the rate terms off, differentiated by Savitzky–Golay at ``sample_rate_hz``
    (this looks ahead by half a window, T/20, which a planned reference allows). Each of
    ``refinements`` re-solves with the derivatives of the previous answer: this converges at
    low rates (1 Hz) but diverges at 50–100 Hz for lag-like fitted dynamic PIs, whose φ steps
    at segment switches make the answer step too; hence 0 by default. Differencing the
    inverse's own past outputs instead is unstable: at 20 kHz the β·ü term feeds a 1/dt²
    gain back into the next sample.
    """
    x = finite_array("x_ref_um", x_ref_um)
    r = np.ascontiguousarray(thresholds_v, dtype=float)
    w = np.ascontiguousarray(weights_um_per_v, dtype=float)
    a1, a2, b1, b2 = (float(v) for v in envelope)
    if not (a1 > 0 and b1 > 0):
        raise ValueError(f"the numerical inverse needs a1 > 0 and b1 > 0, got a1={a1}, b1={b1}")
    alpha = np.zeros(4) if alpha_um_per_v2_s is None else np.ascontiguousarray(alpha_um_per_v2_s, dtype=float)
    beta = np.zeros(4) if beta_um_per_v2_s2 is None else np.ascontiguousarray(beta_um_per_v2_s2, dtype=float)
    lo, hi = (float(v) for v in u_limits_v)
    if not lo < hi:
        raise ValueError(f"u_limits_v must be increasing, got {u_limits_v}")
    y_start = np.zeros(r.size) if y0 is None else np.array(np.broadcast_to(y0, r.shape), dtype=float)

    def solve(envelope_, alpha_, beta_, du, ddu):
        return _invert(x, r, w, float(offset_um), *envelope_, alpha_, beta_, du, ddu, lo, hi, y_start.copy())

    rate_terms = bool(np.any(alpha) or np.any(beta) or a2 != 0.0 or b2 != 0.0)
    if not rate_terms:
        zeros = np.zeros(x.size)
        return solve((a1, a2, b1, b2), alpha, beta, zeros, zeros)
    if du_v_per_s is not None:
        du = finite_array("du_v_per_s", du_v_per_s)
        ddu = finite_array("ddu_v_per_s2", np.zeros_like(du) if ddu_v_per_s2 is None else ddu_v_per_s2)
        if du.size != x.size or ddu.size != x.size:
            raise ValueError(f"x_ref_um has {x.size} samples but the derivatives have {du.size}/{ddu.size}")
    if (du_v_per_s is None or refinements > 0) and not (sample_rate_hz and sample_rate_hz > 0):
        raise ValueError("sample_rate_hz (positive) is needed to estimate u̇ and ü of the inverse")
    if du_v_per_s is None:
        zeros = np.zeros(x.size)
        u = solve((a1, 0.0, b1, 0.0), np.zeros(4), np.zeros(4), zeros, zeros)
        du, ddu = drive_derivatives(u, float(sample_rate_hz))
    u = solve((a1, a2, b1, b2), alpha, beta, du, ddu)
    for _ in range(int(refinements)):
        du, ddu = drive_derivatives(u, float(sample_rate_hz))
        u = solve((a1, a2, b1, b2), alpha, beta, du, ddu)
    return u


# numba keys the cache on this file alone: recompile the solvers when the kernels they call change
drop_stale_caches(globals(), [model_kernels.__file__])
