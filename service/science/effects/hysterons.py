"""Model capacity, not a physical effect: a rate-independent base of a wider family than play operators.

A sum of play operators (the PI) obeys Masing's rule: every reversal curve is the initial loading
curve scaled by two, so its rising and falling branches are one curve turned over. A Bouc–Wen stack
with β ≠ γ, a Preisach material with a general density and real stacks do not obey it, and more play
operators cannot draw what the family cannot (issue 37). Two families of hysterons widen the base,
both rate-independent and linear in their weights (free sign: corrections to the main family, fitted
exactly with it):

- **A Preisach plane of general density.** A play operator of half width r is the Preisach plane's
  relays on the line α − β = 2r with a uniform density along their centre c = (α + β)/2; its output
  y is the centre up to which those relays are switched up. A function g(y) of it is the same line
  with the density g′(c) along the centre, so Σ_j g_j(y_j) over the model's play operators is a
  Preisach plane discrete in width and smooth along the centre (a generalised PI whose output
  envelope is fitted per operator): Chebyshev T_2…T_DEGREE of each play output over the drive's span.
  Its branches need not be one curve turned over; loops may saturate and lean, minor loops stay
  congruent (wiping-out memory holds).
- **Bouc–Wen hysterons** z_k: dz = du − (β|du|z + γ du|z|)/c, β + γ = 1, for β/(β + γ) in
  ``BW_SHARES`` and c in ``BW_SCALES`` (shares of the drive's span), solved exactly along each sample
  (exponential approach, split where z crosses 0). They draw the smooth, non-Masing reversal curves
  of a Duhem-type stack, with no wiping-out memory (a Preisach plane cannot; the ``operators``
  capacity's Duhem operators are the share-1 column alone).

Three grids of this base are offered as alternatives (``LEVELS``; never two in one model): the
default ``hysterons``, ``hysterons_slow`` (slow Duhem hysterons more) and ``hysterons_fine`` (each
play output's map to a higher Chebyshev order). Each fits some stages far better and others worse
on held-out cycles, so the loop takes the one that leaves the lower held-out RMS, a freer grid only
where it clearly earns its columns: capacity grows by validation
(service.science.discovery.base_capacity).

A loop shape wrong at every frequency alike is this base's, never physics.
"""

from __future__ import annotations

import numpy as np

from drivers.jit import njit
from service.science.effects.base import Effect, RecordContext
from service.science.fitting.lsq import Block

#: highest Chebyshev order of each play operator's output map (orders 2…DEGREE are this block's)
DEGREE = 4
#: the fine grid's highest Chebyshev order and its play widths per PI width (``hysterons_fine``)
FINE_DEGREE = 8
FINE_OPERATOR_FACTOR = 3
#: the base's grids, alternatives to each other (``Effect.alternative_to``): the loop takes the one
#: held-out data ask for, and never stacks two
LEVELS = ("hysterons", "hysterons_slow", "hysterons_fine")
#: the slow grid's Duhem hysterons' scales, as shares of the drive's span (``hysterons_slow``)
SLOW_SCALES = (0.4, 0.7)
#: Bouc–Wen hysterons: β/(β + γ) shares, and voltage scales as shares of the drive's span (V/V)
BW_SHARES = (0.2, 0.4, 0.6, 0.8, 1.0)
BW_SCALES = (0.03, 0.08, 0.2)


def envelope_columns(p: np.ndarray, span_v: float, degree: int = DEGREE) -> np.ndarray:
    """(n, n_ops·(degree − 1)) columns T_k(2y/span − 1), k = 2…degree (order-major), of play outputs
    ``p`` (V), normalised by the drive's ``span_v`` (V); dimensionless (their weights are µm)."""
    return _envelope(np.ascontiguousarray(p, dtype=float), float(span_v), int(degree))


@njit(cache=True, nogil=True)
def _envelope(p, span_v, degree):
    n, m = p.shape
    out = np.empty((n, m * (degree - 1)))
    for i in range(n):
        for j in range(m):
            t = 2.0 * p[i, j] / span_v - 1.0
            prev, cur = 1.0, t
            for k in range(degree - 1):
                prev, cur = cur, 2.0 * t * cur - prev
                out[i, k * m + j] = cur
    return out


@njit(cache=True, inline="always")
def _approach(q: float, a: float, k: float) -> float:
    """q after travel a (V) of dq/da = 1 − k·q (exact)."""
    if abs(k * a) < 1e-12:
        return q + a
    return 1.0 / k + (q - 1.0 / k) * np.exp(-k * a)


@njit(cache=True, inline="always")
def bw_step(z: float, du: float, c: float, share: float) -> float:
    """One Bouc–Wen hysteron (scale ``c`` V, β/(β + γ) = ``share``) moved by ``du`` (V), exactly: in
    the direction of motion q = sign(du)·z obeys dq/da = 1 − (β q + γ|q|)/c over the travel a = |du|,
    k = (β + γ)/c = 1/c while q ≥ 0 and k = (β − γ)/c while q < 0."""
    if du == 0.0:
        return z
    s = 1.0 if du > 0.0 else -1.0
    q, left = s * z, abs(du)
    if q < 0.0:  # moving back towards 0: reach it, or stop short
        k = (2.0 * share - 1.0) / c
        need = -q if abs(k * q) < 1e-12 else np.log(1.0 - k * q) / k
        if need >= left:
            return s * min(_approach(q, left, k), 0.0)
        q, left = 0.0, left - need
    return s * _approach(q, left, 1.0 / c)


@njit(cache=True, nogil=True)
def bouc_wen_hysterons(u_v: np.ndarray, scales_v: np.ndarray, shares: np.ndarray) -> np.ndarray:
    """(n, scales × shares) Bouc–Wen hysteron outputs z (V), scale-major, from z = 0 (``bw_step``;
    the approach away from 0, the same for every share of a scale, takes one exponential per scale)."""
    n, m = u_v.size, scales_v.size * shares.size
    out = np.zeros((n, m))
    z = np.zeros(m)
    for i in range(1, n):
        du = u_v[i] - u_v[i - 1]
        if du != 0.0:
            s = 1.0 if du > 0.0 else -1.0
            for a_i in range(scales_v.size):
                c = scales_v[a_i]
                decay = np.exp(-abs(du) / c)
                for b_i in range(shares.size):
                    j = a_i * shares.size + b_i
                    if s * z[j] >= 0.0:
                        z[j] = s * (c + (s * z[j] - c) * decay)
                    else:
                        z[j] = bw_step(z[j], du, c, shares[b_i])
        out[i, :] = z
    return out


class Hysterons(Effect):
    point_symmetric = False
    #: its loops may lean and saturate (issue 37: the base must draw them), so once it is in a model the
    #: symmetry test reads that model's residual: a loop's even part the base draws is not physics (read
    #: from the measured loop, the dynamics bench's mode ring-down was claimed as asymmetry after it)
    draws_any_loop_shape = True
    name = "hysterons"
    kind = "capacity"
    #: twice the PI's play widths (20 for the default 10): the plane is discrete in width, and a density
    #: that changes over a few volts of width (a Jiles–Atherton or Bouc–Wen n = 2 stack) needs the finer
    #: grid (held out at 5 kHz: JA 4.6 → 2.6 nm, Bouc–Wen n = 2 3.2 → 2.3 nm; docs/discovery-evidence.md)
    operator_factor = 2
    alternative_to = LEVELS[1:]
    #: slow Duhem hysterons (share 1) beside the Bouc–Wen ones: voltage scales as shares of the span
    slow_scales: tuple[float, ...] = ()
    #: highest Chebyshev order of each play operator's output map
    degree = DEGREE
    #: refines the first grid's own maps (Effect.adds_memory)
    adds_memory = False
    stage = "capacity"
    signature = (
        "the loop's rising and falling branches differ in shape, not only in position (no Masing rule: a "
        "Bouc–Wen, Preisach or real stack), at all frequencies alike: a Preisach plane of general density and "
        "Bouc–Wen hysterons as the base; a model-capacity change, not physics"
    )

    def blocks(self, ctx: RecordContext) -> list[Block]:
        """Each play operator's output through Chebyshev polynomials of orders 2…DEGREE (µm weights),
        and the Bouc–Wen hysterons of the drive (µm/V weights); free sign."""
        scales = np.asarray(BW_SCALES) * ctx.u_scale_v
        u = np.ascontiguousarray(ctx.u_v, dtype=float)
        out = [
            Block.make("preisach_envelope_um", envelope_columns(ctx.p, ctx.u_scale_v, self.degree)),
            Block.make("bouc_wen_weights_um_per_v", bouc_wen_hysterons(u, scales, np.asarray(BW_SHARES, dtype=float))),
        ]
        if self.slow_scales:
            slow = np.asarray(self.slow_scales) * ctx.u_scale_v
            out.append(Block.make("slow_duhem_weights_um_per_v", bouc_wen_hysterons(u, slow, np.ones(1))))
        return out

    units = {"preisach_envelope_um": "µm", "bouc_wen_weights_um_per_v": "µm/V"}

    def evidence(self, sig, floor):
        return ""


class SlowHysterons(Hysterons):
    """The same base with slow Duhem hysterons more (scales SLOW_SCALES of the drive's span, share
    1: an exponential approach after each reversal, no wiping-out memory). A stack whose branches
    relax over half its span (a Duhem stack with a flat anhysteretic line) needs them: held out at
    5 kHz, 15.8 → 2.3 nm on such a stage in both record forms. Where nothing is that slow, their
    50–85 V memory is poorly held by a long record's rests and holds (Bouc–Wen β < γ, one long
    record: 2.2 → 3.5 nm; Jiles–Atherton 2.9 → 7.4 nm), so it is an alternative grid the loop takes
    only where held-out data ask (docs/discovery-evidence.md)."""

    name = "hysterons_slow"
    alternative_to = (LEVELS[0], LEVELS[2])
    slow_scales = SLOW_SCALES
    #: slow relaxation after each reversal, which the first grid lacks (Effect.adds_memory)
    adds_memory = True
    signature = (
        "as hysterons, with a slow Duhem hysteron (the branches relax over half the drive's span after "
        "each reversal); a model-capacity change, not physics"
    )
    units = {**Hysterons.units, "slow_duhem_weights_um_per_v": "µm/V"}


class FineHysterons(Hysterons):
    """The same base finer on both axes of the Preisach plane: each play operator's output map drawn
    to order FINE_DEGREE (a density that changes sharply along the centre) and FINE_OPERATOR_FACTOR
    × the PI's play widths (sharply across the widths too). A Krasnosel'skii–Pokrovskii kernel's
    8 V ridge smears both: at 2× (a width every 6 V of a 120 V span) its held-out cycles stayed at
    3.6 nm over a 2 nm floor per block, at 3× they reach 2.5 nm; Jiles–Atherton, Bouc–Wen n = 2 and a
    Gaussian Preisach plane are unchanged (docs/discovery-evidence.md)."""

    name = "hysterons_fine"
    alternative_to = LEVELS[:2]
    degree = FINE_DEGREE
    operator_factor = FINE_OPERATOR_FACTOR
    signature = (
        "as hysterons, with each play operator's output map drawn to a higher order (a Preisach density "
        "that changes sharply along the centre); a model-capacity change, not physics"
    )
