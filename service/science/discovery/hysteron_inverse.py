"""The exact inverse of the ``hysterons`` model kind's rate-independent base (issue 37).

The base is x̂ = s·(offset + Σ w_j·y_j + Σ e_jk·T_k(2y_j/S − 1) + Σ b_m·z_m): play operators y_j
(thresholds r_j, V), their Chebyshev envelopes and Bouc–Wen hysterons z_m
(service.science.effects.hysterons), every one a function of the drive's path only. The drive that
follows a reference is then found sample by sample: at each sample, the drive u whose output from the
operators' current state equals the reference (bracketed from the previous drive outwards, then
bisection to ``TOLERANCE_V``), and the states advance with it. The output of a single step is
continuous in u, so a bracket is a solution; where the reference lies outside what the model reaches
within the limits, the nearer limit's drive is taken (the miss is the caller's to refuse).
Units: V in, µm out.
"""

from __future__ import annotations

import numpy as np

from drivers.jit import njit
from service.science.effects.hysterons import BW_SCALES, BW_SHARES, bw_step

#: bisection stops when the bracket is this narrow (V)
TOLERANCE_V = 1e-9
#: first bracket step (V), doubled until the output crosses the reference
FIRST_STEP_V = 0.05


@njit(cache=True, inline="always")
def _output(u, prev_u, plays, zs, model, new_plays, new_zs):
    """The model's output (µm) at drive ``u`` (V) from the state ``plays``/``zs`` reached at ``prev_u``;
    the new state into ``new_plays``/``new_zs``. ``model``: (thresholds, weights, env, degree, span, bw,
    scales, shares, offset)."""
    thresholds, weights, env, degree, span, bw, scales, shares, offset = model
    x = offset
    for j in range(thresholds.size):
        y = max(u - thresholds[j], min(u + thresholds[j], plays[j]))
        new_plays[j] = y
        x += weights[j] * y
        t = 2.0 * y / span - 1.0
        prev, cur = 1.0, t
        for k in range(degree - 1):
            prev, cur = cur, 2.0 * t * cur - prev
            x += env[k * thresholds.size + j] * cur
    for a in range(scales.size):
        for b in range(shares.size):
            m = a * shares.size + b
            z = bw_step(zs[m], u - prev_u if prev_u == prev_u else 0.0, scales[a], shares[b])
            new_zs[m] = z
            x += bw[m] * z
    return x


@njit(cache=True)
def _invert(target, thresholds, weights, env, degree, span, bw, scales, shares, offset, lo, hi):
    n = target.size
    out = np.zeros(n)
    plays = np.zeros(thresholds.size)
    zs = np.zeros(scales.size * shares.size)
    new_plays, new_zs = plays.copy(), zs.copy()
    model = (thresholds, weights, env, degree, span, bw, scales, shares, offset)
    u = 0.0
    for i in range(n):
        pu = np.nan if i == 0 else u  # predict's hysterons start relaxed at the first sample's drive
        f0 = _output(u, pu, plays, zs, model, new_plays, new_zs) - target[i]
        a, fa, b = u, f0, u
        found = f0 == 0.0
        step = 0.05
        while not found:  # widen a bracket on both sides of the previous drive
            for cand in (u + step, u - step):
                c = min(max(cand, lo), hi)
                fc = _output(c, pu, plays, zs, model, new_plays, new_zs) - target[i]
                if fc == 0.0 or (fc > 0.0) != (f0 > 0.0):
                    b, found = c, True
                    break
            if found or (u + step >= hi and u - step <= lo):
                break
            step *= 2.0
        if not found:  # out of reach: the limit whose output is nearer
            f_lo = abs(_output(lo, pu, plays, zs, model, new_plays, new_zs) - target[i])
            f_hi = abs(_output(hi, pu, plays, zs, model, new_plays, new_zs) - target[i])
            b = lo if f_lo < f_hi else hi
        else:
            while abs(b - a) > 1e-9:
                m = 0.5 * (a + b)
                fm = _output(m, pu, plays, zs, model, new_plays, new_zs) - target[i]
                if fm == 0.0:
                    a = b = m
                elif (fm > 0.0) == (fa > 0.0):
                    a, fa = m, fm
                else:
                    b = m
        _output(b, pu, plays, zs, model, new_plays, new_zs)
        plays[:] = new_plays
        zs[:] = new_zs
        u = b
        out[i] = u
    return out


def invertible(model) -> bool:
    """Whether ``model``'s output is the base alone (no other effect, no gauge, no transform)."""
    return list(model.effects) == ["hysterons"]


def hysteron_inverse(model, x_ref_um: np.ndarray, u_limits_v) -> np.ndarray:
    """The drive (V) whose ``model`` output follows ``x_ref_um`` (µm), searched within ``u_limits_v``
    (V), from the relaxed state at 0 V (relative to the model's drive origin)."""
    from service.science.effects.hysterons import DEGREE

    origin = model.u_origin_v
    span = model.scales["u_scale_v"]
    target = model.sign * np.asarray(x_ref_um, dtype=float)
    u = _invert(
        np.ascontiguousarray(target),
        np.asarray(model.thresholds_v, dtype=float),
        np.asarray(model.coef["weights_um_per_v"], dtype=float),
        np.asarray(model.coef["preisach_envelope_um"], dtype=float),
        DEGREE,
        float(span),
        np.asarray(model.coef["bouc_wen_weights_um_per_v"], dtype=float),
        np.asarray(BW_SCALES, dtype=float) * span,
        np.asarray(BW_SHARES, dtype=float),
        float(model.coef["offset_um"][0]),
        float(u_limits_v[0] - origin),
        float(u_limits_v[1] - origin),
    )
    return u + origin
