"""Switched-strain kernels of the hysteresis families other than Preisach, compiled with numba.

Each is rate independent: the state moves with the input increment du (V) alone, whatever the
time it took, and the integration does not depend on how du is cut into samples. Neither is a
sum of play operators (a house rule: the emulator never uses the model family the service fits).

- Bouc–Wen (Bouc 1967, Wen 1976; the piezo form of Low & Guo 1995): a hysteretic voltage h lags
  the drive, dh = A·du − β·|du|·|h|^(n−1)·h − γ·du·|h|^n, and the switched strain is ∝ u − h.
  Integrated with classical Runge–Kutta in substeps of at most ``max_step_v``.
- Maxwell-slip (Goldfarb & Celanovic 1997 for piezo stacks; the smooth elements of the
  generalised Maxwell-slip model, Al-Bender et al. 2005): elasto-slip elements in parallel, each
  a spring deflection δ_i that follows the drive elastically up to ``elastic_fraction``·r_i and
  then yields smoothly, approaching its slip limit r_i exponentially (a Dahl-like transition, not
  the play operator's corner). The switched strain is ∝ u − Σ k_i·δ_i. Integrated exactly.

Called from ``kernels.switched_update``; these functions take scalars and row views only, so they
know nothing of the world's array layout.
"""

from __future__ import annotations

import math

from drivers.jit import njit


@njit(cache=True, inline="always")
def _bw_rate(h, sgn, a_gain, beta, gamma, n):
    """dh/d|u| of Bouc–Wen for a move of sign ``sgn`` (β, γ in 1/V^n)."""
    ah = abs(h)
    if n == 1.0:  # the usual piezo form: no powers
        return sgn * a_gain - beta * h - gamma * sgn * ah
    pn = ah**n
    return sgn * a_gain - beta * h * (pn / ah if ah > 0.0 else 0.0) - gamma * sgn * pn


@njit(cache=True)
def bouc_wen_step(h, du, a_gain, beta, gamma, n, max_step_v):
    """Hysteretic voltage h (V) after the input moved by du (V): RK4 over |du| in equal substeps
    of at most ``max_step_v``."""
    m = abs(du)
    if m == 0.0:
        return h
    sgn = 1.0 if du > 0.0 else -1.0
    steps = int(math.ceil(m / max_step_v))
    s = m / steps
    for _ in range(steps):
        k1 = _bw_rate(h, sgn, a_gain, beta, gamma, n)
        k2 = _bw_rate(h + 0.5 * s * k1, sgn, a_gain, beta, gamma, n)
        k3 = _bw_rate(h + 0.5 * s * k2, sgn, a_gain, beta, gamma, n)
        k4 = _bw_rate(h + s * k3, sgn, a_gain, beta, gamma, n)
        h += s * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
    return h


@njit(cache=True)
def maxwell_slip_step(delta, limit_v, weight, n_el, elastic_fraction, du):
    """Move every element's deflection delta[i] (V) by the input increment du (V), exactly;
    return Σ weight[i]·delta[i] (V). Along the move, y = ±delta grows at the drive's rate up to
    elastic_fraction·r, then as r − (r − y)·exp(−Δ/((1 − elastic_fraction)·r)): slope and value
    continuous, bounded by the slip limit r."""
    m = abs(du)
    sgn = 1.0 if du >= 0.0 else -1.0
    total = 0.0
    for i in range(n_el):
        r = limit_v[i]
        y = sgn * delta[i]
        if m > 0.0:
            knee = elastic_fraction * r
            rest = m
            if y < knee:
                step = min(rest, knee - y)
                y += step
                rest -= step
            if rest > 0.0:
                gap = r - y
                if gap > 1e-12 * r:
                    y = r - gap * math.exp(-rest / ((1.0 - elastic_fraction) * r))
            delta[i] = sgn * y
        total += weight[i] * delta[i]
    return total
