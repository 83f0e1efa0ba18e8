"""Is the measured loop point-symmetric? A model-free test of ``asymmetry``.

For a sine drive u(t) = c − A cos ωt, u(t + T/2) = 2c − u(t). A stack whose response is
point-symmetric about the loop's centre — any Preisach or Prandtl–Ishlinskii loop with a
symmetric density, Bouc–Wen, Maxwell-slip, and all of them behind a linear lag, relaxation, creep
or flexure mode — then answers x(t + T/2) = 2x_c − x(t) in the steady state. So the **even part**
e(t) = [x(t) + x(t + T/2)]/2 − x_c of the mean measured cycle is zero but for noise, whatever the
hysteresis family, and only a loop that is not point-symmetric (electrostriction ∝ u², saturation
of the strain, a gauge curved about its own zero) leaves it. Where the model being diagnosed draws
a point-symmetric loop itself (a PI with linear lags, modes, delays or creep: ``Effect.point_symmetric``)
the test is made on its residual: the even part is then the measurement's less what is not steady
state that the model draws — a flexure mode's ring-down after each block's start, which a 291 Hz
mode leaves in the first cycles of a 100 Hz block and a user's Krasnosel'skii-Pokrovskii stage with
a 450 Hz mode showed as the gauge's curvature. Otherwise (warped operators, segment-switched rate
terms in the model) it is made on the measurement, whose own even part no model drew. Either way
the test cannot mistake a loop shape that the fitted family cannot draw for asymmetry.

Claim rule (as service/science/discovery/decision.py): the even part is significant against the
noise of the mean cycle (χ² test, p < the diagnosis's per-candidate level) and its RMS is at least NOISE_MULTIPLE·σ.
"""

from __future__ import annotations

import numpy as np

from service.science.discovery.decision import ALPHA, NOISE_MULTIPLE
from service.science.discovery.noise import cycles_matrix, repeated_cycles

#: cycles a block needs (after the first, a start-up transient) for its mean cycle
MIN_CYCLES = 2
#: samples per cycle the even part is evaluated on (independent noise samples at most)
POINTS_PER_CYCLE = 400


#: a block's drive is point-symmetric (u(t + T/2) = 2c − u(t)) when its mean cycle's even part is at most
#: this share of its swing: the test's premise; a step-hold's alternating levels (0.8, 0.2, 1.0, 0.4, 0.7,
#: 0 of the range, read as a 1 Hz block) do not repeat cycle to cycle (their mean cycle, a square wave, is
#: point-symmetric), and a point-symmetric stack answers them with an even part
DRIVE_EVEN_SHARE = 0.01


def _drive_point_symmetric(u: np.ndarray, period: float) -> bool:
    """The drive repeats cycle to cycle (noise.repeated_cycles) and its mean cycle is point-symmetric."""
    mat = cycles_matrix(np.asarray(u, dtype=float), period, even=True)
    if mat is None or not repeated_cycles(mat).all():
        return False
    mean = mat.mean(axis=0)
    half = mean.size // 2
    even = 0.5 * (mean[:half] + mean[half:]) - 0.5 * (mean.max() + mean.min())
    return float(np.sqrt(np.mean(even**2))) <= DRIVE_EVEN_SHARE * max(float(np.ptp(mean)), 1e-12)


def even_part(rec, split, series: np.ndarray) -> tuple[np.ndarray, int] | None:
    """The even part (µm) of one periodic block's mean cycle of ``series`` (the record's residual)
    and the number of cycles averaged."""
    period = rec.period_samples(split)
    a, b = split.train[0], split.held_out[1]
    if not period or period < 8:
        return None
    mat = cycles_matrix(series[a:b], period, even=True)  # a half cycle: exactly M/2 points
    if mat is None or mat.shape[0] < MIN_CYCLES or not _drive_point_symmetric(rec.u_v[a:b], period):
        return None
    # a slow trend over the block (creep, drift) is not a loop shape: x(t) + x(t + T/2) grows with it,
    # so the cycle means' linear trend is taken out, sample by sample, before the mean cycle
    k = np.arange(mat.shape[0])[:, None] + np.arange(mat.shape[1])[None, :] / mat.shape[1]
    slope = float(np.polyfit(np.arange(mat.shape[0]), mat.mean(axis=1), 1)[0])
    mat = mat - slope * k
    mean = mat.mean(axis=0)
    m = mean.size
    if m < 8:
        return None
    half = m // 2
    centre = 0.5 * (mean.max() + mean.min())
    even = 0.5 * (mean[:half] + mean[half:]) - centre
    even = even - even.mean()  # an offset is not asymmetry: the centre's estimate carries noise
    step = max(1, half // (POINTS_PER_CYCLE // 2))
    return even[::step], int(mat.shape[0])


def asymmetry_test(records, residuals, noise_um: float, alpha: float = ALPHA) -> dict:
    """``even_rms_um`` (RMS over blocks of the even part of ``residuals``, µm, one per record: the
    model's residuals or the measurements),
    ``p`` of the χ² test against the mean cycle's noise, ``blocks`` used, and ``claimed`` by the rule
    above."""
    chi2, dof, sq, count, used = 0.0, 0, 0.0, 0, 0
    for rec, residual in zip(records, residuals):
        for s in rec.splits_of(own_axis_only=True):
            got = even_part(rec, s, residual)
            if got is None:
                continue
            even, cycles = got
            var = noise_um**2 / (2.0 * cycles)  # half the sum of two independent mean-cycle samples
            if var > 0:
                chi2 += float(np.sum(even**2)) / var
                dof += even.size - 1
            sq += float(np.sum(even**2))
            count += even.size
            used += 1
    if not used or noise_um <= 0:
        return {"even_rms_um": None, "p": 1.0, "blocks": used, "claimed": False}
    from scipy import stats  # imported when used: scipy.stats costs a service 0.4 s of start-up

    rms = float(np.sqrt(sq / count))
    p = float(stats.chi2.sf(chi2, max(dof, 1)))
    return {"even_rms_um": rms, "p": p, "blocks": used, "claimed": bool(p < alpha and rms >= NOISE_MULTIPLE * noise_um)}
