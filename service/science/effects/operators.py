"""Model capacity, not a physical effect: a richer rate-independent hysteresis base.

Three families of hysteresis operators beside the model's play operators, all rate-independent
(functions of the drive's path, not of time):
- twice as many play operators (finer thresholds);
- play operators on a warped drive u·|u|/u_max, so that the operator density may vary along the
  drive, as a generalised PI's envelope does;
- Duhem (Bouc–Wen, n = 1, γ = 0) operators h_k with dh = du − |du|·h/c_k for a few voltage scales
  c_k: smooth exponential approach after each reversal, and no wiping-out memory, so that a loop
  of a Bouc–Wen-like stack (which settles cycle after cycle) is the base's, not a time effect.
A loop shape wrong at every frequency alike is a capacity problem; a physical candidate must beat
this base (service/science/discovery/diagnosis.py)."""

from __future__ import annotations

import numpy as np

from drivers.jit import njit
from service.science.data.units import fmt_nm
from service.science.effects.base import Effect, RecordContext
from service.science.fitting.lsq import Block
from service.science.models.base import equal_thresholds
from service.science.models.kernels import play_operators

OPERATOR_FACTOR = 2
#: Duhem operators' voltage scales, as fractions of the drive's span (V/V)
DUHEM_SCALES = (0.02, 0.05, 0.12, 0.3)


@njit(cache=True, nogil=True)
def duhem_operators(u_v: np.ndarray, scales_v: np.ndarray) -> np.ndarray:
    """(n, k) Duhem operator outputs (V): h_k += du − |du|·h_k/c_k per sample, exact for a step du
    (h relaxes exponentially in |u| travelled: h ← h·e^(−|du|/c) + sign(du)·c·(1 − e^(−|du|/c)))."""
    n, k = u_v.size, scales_v.size
    out = np.zeros((n, k))
    h = np.zeros(k)
    for i in range(1, n):
        du = u_v[i] - u_v[i - 1]
        if du != 0.0:
            a = abs(du)
            s = 1.0 if du > 0.0 else -1.0
            for j in range(k):
                e = np.exp(-a / scales_v[j])
                h[j] = h[j] * e + s * scales_v[j] * (1.0 - e)
        out[i, :] = h
    return out


class Operators(Effect):
    point_symmetric = False
    name = "operators"
    kind = "capacity"
    stage = "capacity"
    signature = (
        "the loop shape itself is not matched (residual repeats cycle to cycle, at all "
        "frequencies alike): more, finer and other hysteresis operators; a model-capacity change, not physics"
    )

    def blocks(self, ctx: RecordContext) -> list[Block]:
        """Play operators (µm/V weights, free sign: a correction to the main family) of the warped
        drive u·|u|/u_max (V), thresholds as the main family's over the data set's drive scale; and
        Duhem operators of the drive (µm/V, free sign)."""
        warped_v = ctx.u_v * np.abs(ctx.u_v) / ctx.u_scale_v
        thresholds = equal_thresholds(ctx.u_scale_v, ctx.p.shape[1])
        scales = np.asarray(DUHEM_SCALES) * ctx.u_scale_v
        return [
            Block.make("warped_weights_um_per_v", play_operators(warped_v, thresholds)),
            Block.make("duhem_weights_um_per_v", duhem_operators(np.ascontiguousarray(ctx.u_v, dtype=float), scales)),
        ]

    units = {"warped_weights_um_per_v": "µm/V", "duhem_weights_um_per_v": "µm/V"}
    operator_factor = OPERATOR_FACTOR
    in_flexible_base = True

    def evidence(self, sig, floor):
        rep, nf = floor.get("repeatable_rms_um"), floor.get("noise_floor_um")
        return (
            f"the residual repeats cycle to cycle ({fmt_nm(rep or 0)} repeatable vs {fmt_nm(nf or 0)} noise): "
            "the loop shape needs more hysteresis capacity (finer play operators) — not a physical effect"
        )
