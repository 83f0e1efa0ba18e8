"""The static PI model (eq. 2) and the paper's dynamic PI model (eq. 3–4).

Both are linear in their parameters once the play-operator outputs P (V) are known:
  static:  x = Σ ω_i P_i + offset
  dynamic: x = Σ (ω_i + α_s u̇ + β_s ü) P_i + offset = Σ ω_i P_i + (α_s u̇ + β_s ü) Σ_i P_i + offset
so fitting them is one bounded least-squares solve over their design blocks.
"""

from __future__ import annotations

import numpy as np

from service.science.fitting.lsq import Block
from service.science.models.base import HysteresisModel
from service.science.models.contract import Drive
from service.science.models.inverse import analytic_pi_inverse, numerical_inverse
from service.science.models.kernels import play_operators, segment_index


class StaticPI(HysteresisModel):
    """Eq. 2 with a free output offset: ``x = Σ ω_i P_{r_i}[u] + offset_um`` (ω in µm/V, ω ≥ 0)."""

    name = "static_pi"
    _param_names = ("weights_um_per_v", "offset_um")

    def blocks(self, drive: Drive) -> list[Block]:
        p = play_operators(self.operator_input(drive.u_v), self.thresholds_v)
        return [Block.make("weights_um_per_v", p, lower=0.0)] + self._offset_blocks(p.shape[0])

    def inverse(self, x_ref_um, *, sample_rate_hz=None, u_limits_v=None, method: str = "analytic"):
        """Voltage (V) that makes the model output ``x_ref_um`` from relaxed operators.

        ``method="analytic"`` is eq. 14–17 (needs ω_1 > 0; ignores ``u_limits_v``);
        ``"numerical"`` is the exact per-sample inverse. ``sample_rate_hz`` is unused (rate-independent).
        """
        self._require_fitted()
        x_ref_um = self.in_model_direction(x_ref_um)
        if method == "analytic":
            return (
                analytic_pi_inverse(x_ref_um, self.thresholds_v, self.weights_um_per_v, self.offset_um)
                + self.u_origin_v
            )
        if method == "numerical":
            return (
                numerical_inverse(
                    x_ref_um,
                    self.thresholds_v,
                    self.weights_um_per_v,
                    self.offset_um,
                    u_limits_v=self.inverse_limits(u_limits_v),
                )
                + self.u_origin_v
            )
        raise ValueError(f"unknown inverse method {method!r}: use 'analytic' or 'numerical'")


def segment_columns(du: np.ndarray, ddu: np.ndarray, operator_sum: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Columns (n, 4) multiplying α_1..4 and β_1..4: ``[s==k]·u̇·ΣP`` and ``[s==k]·ü·ΣP``."""
    seg = segment_index(np.ascontiguousarray(du), np.ascontiguousarray(ddu))
    rows = np.arange(seg.size)
    col_a, col_b = np.zeros((seg.size, 4)), np.zeros((seg.size, 4))
    col_a[rows, seg] = du * operator_sum
    col_b[rows, seg] = ddu * operator_sum
    return col_a, col_b


class DynamicPI(HysteresisModel):
    """Eq. 4: ``x = Σ (ω_i + α_s u̇ + β_s ü) P_{r_i}[u] + offset_um``.

    α in µm·s/V² (``alpha_um_per_v2_s``), β in µm·s²/V² (``beta_um_per_v2_s2``), segment s
    from the signs of (u̇, ü) per eq. 3. ``fit`` solves ω ≥ 0, α, β and the offset jointly
    by exact least squares; the paper's two-stage and PSO procedures are in ``service.science.models.procedures``.
    """

    #: why a feedforward plan refuses this model's inverse when it misses (service.science.control.session)
    inverse_advice = (
        "The paper's dynamic PI inverse diverges sample by sample at 50–100 Hz (segment-switched "
        "weights), and solving its drive period by period did not reach the reference either; use a "
        "static_pi or composite model"
    )

    name = "dynamic_pi"
    rate_dependent = True
    described_effects = ("hysteresis", "rate_dependence")
    _param_names = ("weights_um_per_v", "alpha_um_per_v2_s", "beta_um_per_v2_s2", "offset_um")

    def __init__(self, n_operators: int = 10, thresholds_v=None, fit_offset: bool = True):
        super().__init__(n_operators, thresholds_v, fit_offset)
        self.alpha_um_per_v2_s = np.zeros(4)
        self.beta_um_per_v2_s2 = np.zeros(4)

    def blocks(self, drive: Drive) -> list[Block]:
        p = play_operators(self.operator_input(drive.u_v), self.thresholds_v)
        du, ddu = drive.derivatives()
        col_a, col_b = segment_columns(du, ddu, p.sum(axis=1))
        return [
            Block.make("weights_um_per_v", p, lower=0.0),
            Block.make("alpha_um_per_v2_s", col_a),
            Block.make("beta_um_per_v2_s2", col_b),
        ] + self._offset_blocks(p.shape[0])

    @classmethod
    def from_static(cls, static: StaticPI) -> DynamicPI:
        """A dynamic PI with the static weights/offset and zero rate terms."""
        model = cls(thresholds_v=static.thresholds_v, fit_offset=static.fit_offset)
        model.weights_um_per_v = static.weights_um_per_v.copy()
        model.offset_um = static.offset_um
        model.sign = static.sign
        model.u_origin_v = static.u_origin_v
        return model

    def inverse(
        self,
        x_ref_um,
        *,
        sample_rate_hz=None,
        u_limits_v=None,
        du_v_per_s=None,
        ddu_v_per_s2=None,
        refinements: int = 0,
    ):
        """Voltage (V) for reference ``x_ref_um`` sampled at ``sample_rate_hz``.

        u̇, ü of the answer are ``du_v_per_s``/``ddu_v_per_s2`` when known (a planned waveform),
        else those of the static inverse of the reference (see :func:`numerical_inverse`);
        ``refinements`` re-solves with the answer's own.
        """
        self._require_fitted()
        return (
            numerical_inverse(
                self.in_model_direction(x_ref_um),
                self.thresholds_v,
                self.weights_um_per_v,
                self.offset_um,
                sample_rate_hz,
                alpha_um_per_v2_s=self.alpha_um_per_v2_s,
                beta_um_per_v2_s2=self.beta_um_per_v2_s2,
                du_v_per_s=du_v_per_s,
                ddu_v_per_s2=ddu_v_per_s2,
                refinements=refinements,
                u_limits_v=self.inverse_limits(u_limits_v),
            )
            + self.u_origin_v
        )
