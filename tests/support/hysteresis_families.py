"""Three more rate-independent stack materials for issue 37's matrix, built without the product's code
(every figure in µm for a drive in V; each stroke about 12 µm over 120 V with a loop 10–20 % wide).

- ``jiles_atherton_um``: the Jiles–Atherton domain-wall model with the drive as the field,
  H = u / scale_v: the anhysteretic Langevin curve Man(He) = coth(He/a) − a/He of the effective field
  He = H + α·M, the irreversible part dMirr/dH = (Man − Mirr) / (δ·k − α·(Man − Mirr)) (held where
  δ·(Man − Mirr) < 0, the usual correction) and the reversible part c·(Man − Mirr). Its loops narrow
  and tilt with the level: neither congruent nor Masing.
- ``coleman_hodgdon_um``: the Coleman–Hodgdon (Duhem) model dy = α·|du|·(a·u − y) + b·du, whose
  branches relax exponentially (in the drive) towards the anhysteretic line.
- ``krasnoselskii_pokrovskii_um``: a sum of Krasnosel'skii–Pokrovskii hysterons (relays with ramps
  of width ``ridge_v`` instead of jumps) on a triangular grid of thresholds, with a density that
  falls with the hysteron's width and is centred in the drive's range.

Each is integrated along the drive in sub-steps (numba), as a stack's state follows its drive.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _langevin(x):
    if abs(x) < 1e-4:
        return x / 3.0
    return 1.0 / np.tanh(x) - 1.0 / x


@njit(cache=True)
def _jiles_atherton_m(h, a, k, alpha, c, step):
    m_out = np.zeros(h.size)
    m_irr = 0.0
    m = 0.0
    for i in range(1, h.size):
        dh_total = h[i] - h[i - 1]
        n = max(1, int(np.ceil(abs(dh_total) / step)))
        dh = dh_total / n
        hh = h[i - 1]
        delta = 1.0 if dh_total >= 0 else -1.0
        for _ in range(n):
            hh += dh
            man = _langevin((hh + alpha * m) / a)
            gap = man - m_irr
            if delta * gap > 0:
                m_irr += gap / (delta * k - alpha * gap) * dh
            m = m_irr + c * (man - m_irr)
        m_out[i] = m
    return m_out


def jiles_atherton_um(u_v, scale_v=40.0, a=0.5, k=0.6, alpha=0.05, c=0.3, d_um_per_v=0.05, h_um=9.0):
    """x = d·u + h·M(u/scale_v) (µm): a Jiles–Atherton polarisation with the drive as its field."""
    h = np.ascontiguousarray(u_v, dtype=float) / scale_v
    return d_um_per_v * np.asarray(u_v) + h_um * _jiles_atherton_m(h, a, k, alpha, c, 0.002)


@njit(cache=True)
def _coleman_hodgdon(u, alpha, a, b, substep_v):
    y = np.zeros(u.size)
    for i in range(1, u.size):
        du_total = u[i] - u[i - 1]
        n = max(1, int(np.ceil(abs(du_total) / substep_v)))
        du = du_total / n
        uu, yy = u[i - 1], y[i - 1]
        for _ in range(n):
            yy += alpha * abs(du) * (a * uu - yy) + b * du
            uu += du
        y[i] = yy
    return y


def coleman_hodgdon_um(u_v, alpha_per_v=0.04, a_um_per_v=0.1, b_um_per_v=0.055):
    """The Coleman–Hodgdon branch y(u) (µm): loops ±(a − b)/α about the line a·u."""
    return _coleman_hodgdon(np.ascontiguousarray(u_v, dtype=float), alpha_per_v, a_um_per_v, b_um_per_v, 0.25)


@njit(cache=True)
def _kp_sum(u, low, high, weights, ridge_v):
    state = np.zeros(low.size)
    out = np.zeros(u.size)
    for i in range(u.size):
        total = 0.0
        for j in range(low.size):
            up = min(1.0, max(0.0, (u[i] - high[j]) / ridge_v + 1.0))  # pushes the hysteron on above ``high``
            down = min(1.0, max(0.0, (u[i] - low[j]) / ridge_v))  # lets it off below ``low``
            state[j] = min(max(state[j], up), down)
            total += weights[j] * state[j]
        out[i] = total
    return out


def krasnoselskii_pokrovskii_um(u_v, lo_v=-20.0, hi_v=140.0, ridge_v=8.0, d_um_per_v=0.05, h_um=6.0, grid=28):
    """x = d·u + h·Σ w·KP hysteron (µm), the weights a density exp(−((m − centre)/(0.35·span))²) ·
    exp(−r/(0.15·span)) in the hysteron's centre m and half width r (a triangular grid on lo…hi)."""
    edges = np.linspace(lo_v, hi_v, grid)
    low, high = np.meshgrid(edges, edges, indexing="ij")
    keep = high > low
    low, high = low[keep], high[keep]
    span, centre = hi_v - lo_v, 0.5 * (hi_v + lo_v)
    m, r = 0.5 * (low + high), 0.5 * (high - low)
    w = np.exp(-(((m - centre) / (0.35 * span)) ** 2)) * np.exp(-r / (0.15 * span))
    w = w / w.sum()
    u = np.ascontiguousarray(u_v, dtype=float)
    return d_um_per_v * u + h_um * _kp_sum(u, low, high, w, ridge_v)
