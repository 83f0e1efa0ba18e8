"""A feedforward drive for a periodic reference that a model's sample-by-sample inverse misses.

Some models' inverses do not converge along a fast reference: the paper's dynamic PI switches its
rate weights with the signs of u̇ and ü (eq. 3), so a per-sample inverse, which must guess u̇ and ü
of the answer before it has it, steps at each switch and misses the reference (5 % of the range on
the paper's ellipses at 100 Hz). The tracked ellipse is periodic, so in its steady state the drive is
one period repeated: written as a short Fourier series, the drive whose model output follows the
reference's period is found by least squares on the model's own forward prediction (which knows
u̇ and ü of the drive it is given). The ramps keep the per-sample inverse, cross-faded into the
steady drive over one period.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

#: harmonics of the drive's Fourier series (the ellipse itself has one; the hysteresis adds the rest)
HARMONICS = 8
#: periods run through the model before its last one is compared (its operators settle in one)
SETTLE_PERIODS = 2


def periodic_drive_v(model, u_v: np.ndarray, x_ref_um: np.ndarray, sample_rate_hz: float, period: int, steady: slice):
    """``u_v`` (V) with its steady periods replaced by the repeated period whose ``model`` output
    follows ``x_ref_um`` (µm) over one period (``period`` samples, ``steady`` the periods between the
    ramps); the last ramp period before and the first after are cross-fades. The model's forward
    prediction (``model.predict``) is the only thing asked of it."""
    phase = 2 * np.pi * np.arange(period) / period
    basis = np.column_stack(
        [np.ones(period)] + [f(k * phase) for k in range(1, HARMONICS + 1) for f in (np.cos, np.sin)]
    )
    target = np.asarray(x_ref_um, dtype=float)[steady][:period]
    start = np.linalg.lstsq(basis, np.asarray(u_v, dtype=float)[steady][:period], rcond=None)[0]

    def miss(coef):
        drive = np.tile(basis @ coef, SETTLE_PERIODS + 1)
        return np.asarray(model.predict(drive, sample_rate_hz=sample_rate_hz), dtype=float)[-period:] - target

    one_period = basis @ least_squares(miss, start, method="lm", x_scale="jac", max_nfev=400).x
    out = np.array(u_v, dtype=float)
    first, stop = steady.start, steady.stop
    out[first:stop] = np.tile(one_period, (stop - first) // period)
    fade_in = 0.5 * (1 - np.cos(np.pi * np.arange(period) / period))
    if first >= period:
        out[first - period : first] = (1 - fade_in) * out[first - period : first] + fade_in * one_period
    if stop + period <= out.size:
        out[stop : stop + period] = fade_in * out[stop : stop + period] + (1 - fade_in) * one_period
    return out
