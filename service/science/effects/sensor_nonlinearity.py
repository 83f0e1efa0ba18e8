"""Sensor nonlinearity: the gauge's own curvature. A capacitance probe that is not linearised (or a
slightly tilted target) reads x_m = x + h·(c₂e² + c₃e³), e = (x − x_mid)/h, with x_mid and h the middle and the half
span of the measured range (µm): c₂ the bow and c₃ the S-bend at the ends, as fractions of h.

It is a function of the position x, not of the drive u or the loop's state, so it is a stage of its
own (``output``) after everything else: x̂ = z + h·(c₂e² + c₃e³) of z, with z the model's output
before the gauge. The weights and c₂, c₃ are fitted by alternating least squares (c with z fixed, then
everything again); the curvature is small, so a few rounds converge.

The S-bend alone bends a point-symmetric loop into another point-symmetric loop, which the flexible
hysteresis base draws as well; the bow is what a point-symmetric stack cannot make, so the model-free
asymmetry test sees it first. On a quasi-static loop x is itself a function of the drive and the
loop's state, so a gauge's bow and a stack's asymmetry (asymmetry.py) bend the loop alike; they
part only where x at one (u, state) differs (the branches' width, rate effects, creep). The
diagnosis weighs the two head to head (service.science.discovery.diagnosis).
"""

from __future__ import annotations

import numpy as np

from service.science.effects.base import Effect

#: alternating least-squares rounds (weights, then the bow on the new output)
OUTPUT_ROUNDS = 4
#: Newton steps of the gauge's inverse (quadratic convergence from z = x; 1e-12 µm after 4 at 3 % bow)
INVERSE_NEWTON_STEPS = 6


class SensorNonlinearity(Effect):
    point_symmetric = False
    name = "sensor_nonlinearity"
    stage = "output"
    block_name = "gauge_bow_um"
    signature = (
        "the loop's bow follows the measured position x, not the drive: at one drive the "
        "ascending and descending branches are bent by different amounts — the gauge's own curvature"
    )

    @staticmethod
    def columns(z_um: np.ndarray, x_mid_um: float, x_half_um: float) -> np.ndarray:
        """The gauge's columns (n, 2) for the model output ``z_um`` (µm): h·e², h·e³ with
        e = (z − x_mid)/h, the bow and the S-bend of the reading (µm at the ends of the range)."""
        h = max(x_half_um, 1e-12)
        e = (np.asarray(z_um, dtype=float) - x_mid_um) / h
        return h * np.column_stack([e * e, e * e * e])

    def invert(self, x_um: np.ndarray, coef: np.ndarray, x_mid_um: float, x_half_um: float) -> np.ndarray:
        """z (µm) with z + columns(z)·coef = x, by Newton from z = x (the curvature is a few %)."""
        x = np.asarray(x_um, dtype=float)
        h = max(x_half_um, 1e-12)
        c2, c3 = float(coef[0]), float(coef[1])
        z = x.copy()
        for _ in range(INVERSE_NEWTON_STEPS):
            e = (z - x_mid_um) / h
            f = z + h * (c2 * e * e + c3 * e**3) - x
            z = z - f / np.maximum(1.0 + 2.0 * c2 * e + 3.0 * c3 * e * e, 0.1)
        return z

    def describe(self, theta, values):
        p = self.parameters(theta, values, {}, 1.0)
        return (
            ""
            if not p
            else (
                f"gauge bow {p['gauge_bow_pct']:.3g} % and S-bend {p['s_bend_pct']:.3g} % of "
                "the half span at the ends of the range"
            )
        )

    def parameters(self, theta, values, scales, sign):
        """``gauge_bow_pct`` and ``s_bend_pct``: the reading's bow and S-bend at the ends of the range (%
        of the half span), as the words print them."""
        w = values.get(self.block_name)
        return {} if w is None else {"gauge_bow_pct": 100 * float(w[0]), "s_bend_pct": 100 * float(w[1])}

    units = {"gauge_bow_um": "µm", "gauge_bow_pct": "%", "s_bend_pct": "%"}
    rule = "a drive that spans a range (any loop); told from asymmetry where x at one drive differs"
    inverse = "invert"
    emulator_bench = "sensor_nonlinearity"

    def evidence(self, sig, floor):
        return (
            "the loop's bow follows the measured position x rather than the drive: the gauge's own curvature "
            "(an unlinearised capacitance probe, a tilted target) — a property of the measurement, not of the "
            "stack: sensor_nonlinearity"
        )
