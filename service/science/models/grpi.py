"""The generalised rate-dependent PI model (GRPI, eq. 13).

Rate-dependent play operators run between the envelopes h_l = a1 u + a2|u̇| and
h_r = b1 u + b2|u̇| (V; a2, b2 in s); x = Σ ω_i P_{h,r_i}[u] + offset. Weights are a
bounded least-squares solve given (a1, a2, b1, b2); those four come from a small outer
search on the variable-projection residual, started at the static PI (1, 0, 1, 0).
"""

from __future__ import annotations

import numpy as np

from service.science.fitting.lsq import Block, separable_least_squares, stack_blocks
from service.science.models.base import HysteresisModel
from service.science.models.contract import Drive
from service.science.models.inverse import numerical_inverse
from service.science.models.kernels import envelope_play_operators, grpi_envelopes

ENVELOPE_NAMES = ("a1", "a2_s", "b1", "b2_s")
#: Lower bound on a1, b1: the envelopes must rise with u for the model to be invertible.
MIN_ENVELOPE_SLOPE = 1e-3


class GRPI(HysteresisModel):
    """Eq. 13 with a free output offset. ``envelope`` = (a1, a2_s, b1, b2_s)."""

    name = "grpi"
    rate_dependent = True
    _param_names = ("weights_um_per_v", "offset_um") + ENVELOPE_NAMES
    _scalar_names = ("offset_um",) + ENVELOPE_NAMES

    def __init__(self, n_operators: int = 10, thresholds_v=None, fit_offset: bool = True):
        super().__init__(n_operators, thresholds_v, fit_offset)
        self.a1, self.a2_s, self.b1, self.b2_s = 1.0, 0.0, 1.0, 0.0
        self.fit_report: dict | None = None

    @property
    def envelope(self) -> tuple[float, float, float, float]:
        return tuple(getattr(self, k) for k in ENVELOPE_NAMES)

    def operator_outputs(self, drive: Drive, envelope=None) -> np.ndarray:
        """Rate-dependent play-operator outputs (n, n_operators) in V."""
        a1, a2, b1, b2 = self.envelope if envelope is None else envelope
        du, _ = drive.derivatives()
        h_l, h_r = grpi_envelopes(self.operator_input(drive.u_v), du, a1, a2, b1, b2)
        return envelope_play_operators(h_l, h_r, self.thresholds_v)

    def blocks(self, drive: Drive, envelope=None) -> list[Block]:
        p = self.operator_outputs(drive, envelope)
        return [Block.make("weights_um_per_v", p, lower=0.0)] + self._offset_blocks(p.shape[0])

    def fit(self, data, row_weights=None) -> GRPI:
        """Weights by bounded LS inside a least-squares search over (a1, a2, b1, b2);
        ``row_weights`` as in :meth:`HysteresisModel.fit`."""
        items, target, row_weights = self._prepare(data, row_weights)
        signals = [Drive.of(s) for s in items]
        speed = max(float(np.max(np.abs(s.derivatives()[0]))) for s in signals)
        span = max(float(np.ptp(s.u_v)) for s in signals)
        a_scale = span / speed if speed > 0 else 1.0  # a2|u̇| of order the drive span at scale 1

        def make_blocks(theta):
            return stack_blocks([self.blocks(s, tuple(theta)) for s in signals])

        sol = separable_least_squares(
            make_blocks,
            target,
            theta0=[1.0, 0.0, 1.0, 0.0],
            theta_scale=[1.0, a_scale, 1.0, a_scale],
            bounds=([MIN_ENVELOPE_SLOPE, -np.inf, MIN_ENVELOPE_SLOPE, -np.inf], np.inf),
            row_weights=row_weights,
        )
        self.set_parameters({**dict(zip(ENVELOPE_NAMES, sol.theta)), **sol.linear.values})
        self.train_rms_um = sol.linear.rms
        self.fit_report = {"nfev": sol.nfev, "njev": sol.njev, "message": sol.message}
        return self

    def inverse(self, x_ref_um, *, sample_rate_hz=None, u_limits_v=None, du_v_per_s=None, refinements: int = 0):
        """Voltage (V) for ``x_ref_um``; |u̇| as in :func:`numerical_inverse`."""
        self._require_fitted()
        u_v = numerical_inverse(
            self.in_model_direction(x_ref_um),
            self.thresholds_v,
            self.weights_um_per_v,
            self.offset_um,
            sample_rate_hz,
            envelope=self.envelope,
            du_v_per_s=du_v_per_s,
            refinements=refinements,
            u_limits_v=self.inverse_limits(u_limits_v),
        )
        return u_v + self.u_origin_v
