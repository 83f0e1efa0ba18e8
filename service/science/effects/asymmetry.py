"""Asymmetry: a loop that is not point-symmetric (electrostriction ∝ u², saturation ∝ u³, and
a saturating hysteretic strain ∝ S² whose size depends on the field, ∝ u·S): columns in the
normalised drive u/u_max and the normalised hysteretic state S = Σ_{i≥1} P_i / u_max.
(S³ is left out on purpose: it also bends a symmetric Preisach loop, so on a bench without
asymmetry it would claim the hysteresis model's own shape error as asymmetry.)"""

from __future__ import annotations

import numpy as np

from service.science.effects.base import Effect, RecordContext
from service.science.fitting.lsq import Block


class Asymmetry(Effect):
    point_symmetric = False
    name = "asymmetry"
    signature = (
        "the branch-mean residual is an even (parabolic) or saturating function of the "
        "drive: the loop is not point-symmetric about its centre"
    )

    def blocks(self, ctx: RecordContext) -> list[Block]:
        u = ctx.u_v / ctx.u_scale_v
        s = ctx.p[:, 1:].sum(axis=1) / ctx.u_scale_v if ctx.p.shape[1] > 1 else u
        return [Block.make(self.block_name, np.column_stack([u**2, u**3, s**2, u * s]))]

    block_name = "asymmetry_um"
    #: the columns of ``asymmetry_um``, in order, as the parameters name them
    TERMS = ("u2", "u3", "s2", "us")

    def parameters(self, theta, values, scales, sign):
        """The output each column adds at the full drive scale (column value 1: u = u_scale_v, S = 1), in
        nm and the gauge's sign: ``asymmetry_u2_nm`` (∝ u², electrostriction), ``asymmetry_u3_nm`` (∝ u³,
        saturation), ``asymmetry_s2_nm`` (∝ S²) and ``asymmetry_us_nm`` (∝ u·S): the stored weights
        ``asymmetry_um`` × 1000 (they were missing, so Discover's "Effects found" showed "–")."""
        weights = values.get(self.block_name)
        if weights is None:
            return {}
        return {f"asymmetry_{t}_nm": sign * float(w) * 1e3 for t, w in zip(self.TERMS, np.ravel(weights))}

    units = {"asymmetry_um": "µm", **{f"asymmetry_{t}_nm": "nm" for t in TERMS}}
    rule = "a drive that spans a range (any loop)"
    emulator_bench = "asymmetry"
    in_flexible_base = True
    separated_from = {
        "sensor_nonlinearity": (
            "on a quasi-static loop x is itself a function of the drive and the loop's state, so "
            "a gauge's bow and a stack's asymmetry bend it alike; they part where x at one drive "
            "differs (the branches' width, higher rates), so more cycles at more rates give the "
            "head-to-head its power. An independent measurement of x (a second gauge, an "
            "interferometer) settles it",
            {"waveform": "sine", "frequencies_hz": [1.0, 10.0, 50.0, 100.0, 200.0], "cycles": 10},
        )
    }

    def evidence(self, sig, floor):
        v = sig.get("even_fraction")
        shape = f"a parabola in the drive carries {100 * v:.0f} % of the loop residual: " if v is not None else ""
        return (
            shape + "the loop is not point-symmetric about its centre even with finer operators, which draw any "
            "point-symmetric loop: an electrostrictive (∝ u²) or saturating stack — a property of the loop, "
            "not of time or rate (a gauge's own curvature would bend the output as a function of x instead): "
            "asymmetry"
        )
