"""What every hysteresis model shares: thresholds (eq. 9), input handling, the
linear-in-parameters fit over design blocks, prediction, and JSON round trips.
"""
from __future__ import annotations

from typing import ClassVar, Sequence

import numpy as np

from service.science.models.data import Series, as_series_list, finite_array
from service.science.fitting.lsq import Block, design_matrix, solve_blocks, stack_blocks
from service.science.data.signals import savgol_derivatives, sensitivity_sign


def equal_thresholds(u_max_v: float, n_operators: int) -> np.ndarray:
    """Eq. 9: n thresholds equally spaced from 0 below max(u)/2 (120 V, n=10 → 0, 6, …, 54 V)."""
    if n_operators < 1:
        raise ValueError(f"n_operators must be at least 1, got {n_operators}")
    if not u_max_v > 0:
        raise ValueError(f"max(u_v) must be positive to place thresholds, got {u_max_v:g} V")
    return np.arange(n_operators) * (u_max_v / (2.0 * n_operators))


class Signal:
    """A drive to predict from: u (V), its sample rate and lazily its derivatives."""

    def __init__(self, u_v, sample_rate_hz=None, du_v_per_s=None, ddu_v_per_s2=None):
        if isinstance(u_v, Series):
            self.u_v, self.sample_rate_hz = u_v.u_v, u_v.sample_rate_hz
            self._series = u_v
            return
        self._series = None
        self.u_v = finite_array("u_v", u_v)
        self.sample_rate_hz = sample_rate_hz
        self._given = None
        if du_v_per_s is not None or ddu_v_per_s2 is not None:
            if du_v_per_s is None or ddu_v_per_s2 is None:
                raise ValueError("give both du_v_per_s and ddu_v_per_s2, or neither")
            du, ddu = finite_array("du_v_per_s", du_v_per_s), finite_array("ddu_v_per_s2", ddu_v_per_s2)
            for name, arr in (("du_v_per_s", du), ("ddu_v_per_s2", ddu)):
                if arr.size != self.u_v.size:
                    raise ValueError(f"u_v has {self.u_v.size} samples but {name} has {arr.size}")
            self._given = (du, ddu)

    def derivatives(self) -> tuple[np.ndarray, np.ndarray]:
        if self._series is not None:
            return self._series.derivatives()
        if self._given is None:
            if self.sample_rate_hz is None or not float(self.sample_rate_hz) > 0:
                raise ValueError("sample_rate_hz (positive) is needed to estimate u̇ and ü for a rate-dependent model")
            self._given = savgol_derivatives(self.u_v, float(self.sample_rate_hz))
        return self._given


class HysteresisModel:
    """Base of the PI family. Subclasses define ``name``, ``_param_names`` and ``blocks``."""

    name: ClassVar[str] = ""
    rate_dependent: ClassVar[bool] = False
    _param_names: ClassVar[tuple[str, ...]] = ()
    _scalar_names: ClassVar[tuple[str, ...]] = ("offset_um",)
    _config_names: ClassVar[tuple[str, ...]] = ("n_operators", "fit_offset")

    def __init__(self, n_operators: int = 10, thresholds_v=None, fit_offset: bool = True):
        self.thresholds_v = None if thresholds_v is None else np.asarray(thresholds_v, dtype=float)
        self.n_operators = int(n_operators if thresholds_v is None else len(self.thresholds_v))
        self.fit_offset = bool(fit_offset)
        self.weights_um_per_v: np.ndarray | None = None
        self.offset_um = 0.0
        self.train_rms_um: float | None = None
        self.sign = 1.0       #: −1 when the gauge reads against the drive: fitted to −x, predicts −(…)
        #: the drive (V) the operators count from: 0 V, or the lowest drive of the fitted records when
        #: it went below 0 V (a bipolar or negative record); thresholds span the drive above it
        self.u_origin_v = 0.0

    # -- the design -----------------------------------------------------------------
    def blocks(self, signal: Signal) -> list[Block]:
        """Design blocks for one record (current nonlinear parameters)."""
        raise NotImplementedError

    def _offset_blocks(self, n: int) -> list[Block]:
        return [Block.make("offset_um", np.ones(n))] if self.fit_offset else []

    def design_blocks(self, series: Series) -> list[Block]:
        """Named column blocks with bounds for ``series``; stack further blocks to extend the fit."""
        self._require_thresholds()
        return self.blocks(Signal(series))

    def design_matrix(self, series: Series) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(A (n, p), lower (p,), upper (p,)) such that ``predict(series) = A @ parameters``."""
        return design_matrix(self.design_blocks(series))

    # -- fitting ----------------------------------------------------------------------
    def _prepare(self, data, row_weights=None) -> tuple[list[Series], np.ndarray, np.ndarray | None]:
        """(records, stacked x_um, validated row weights or None); sets thresholds if unset."""
        items = as_series_list(data)
        target = np.concatenate([s.require_x() for s in items])
        self.sign = sensitivity_sign(np.concatenate([s.u_v for s in items]), target)
        target = self.sign * target
        if row_weights is not None:
            row_weights = finite_array("row_weights", row_weights)
            if row_weights.size != target.size:
                raise ValueError(f"the records have {target.size} samples but row_weights has {row_weights.size}")
            if np.any(row_weights < 0) or not np.any(row_weights > 0):
                raise ValueError("row_weights must be non-negative and not all zero")
        if self.thresholds_v is None:
            self.u_origin_v = min(0.0, min(float(s.u_v.min()) for s in items))
            u_max_v = max(float(s.u_v.max()) for s in items)
            self.thresholds_v = equal_thresholds(u_max_v - self.u_origin_v, self.n_operators)
        return items, target, row_weights

    def stacked_blocks(self, items: Sequence[Series]) -> list[Block]:
        return stack_blocks([self.blocks(Signal(s)) for s in items])

    def fit(self, data, row_weights=None) -> "HysteresisModel":
        """Least squares over all records jointly, with each block's bounds.

        ``row_weights`` (one per sample of the stacked records, ≥ 0) weights the residual;
        zero-weight rows still drive the operator states (e.g. held-out cycles).
        """
        items, target, row_weights = self._prepare(data, row_weights)
        solution = solve_blocks(self.stacked_blocks(items), target, row_weights)
        self.set_parameters(solution.values)
        self.train_rms_um = solution.rms
        return self

    def set_parameters(self, values: dict) -> None:
        """Set the model's parameters from ``{name: values}`` (as ``solve_blocks`` returns);
        names that are not this model's (e.g. appended effect blocks) are ignored."""
        for key, val in values.items():
            if key in self._scalar_names:
                setattr(self, key, float(np.atleast_1d(val)[0]))
            elif key in self._param_names:
                setattr(self, key, np.array(val, dtype=float))

    def operator_input(self, u_v) -> np.ndarray:
        """The drive as the operators see it: ``u_v − u_origin_v`` (V)."""
        return np.asarray(u_v, dtype=float) - self.u_origin_v

    def inverse_limits(self, u_limits_v) -> tuple[float, float]:
        """Drive limits (V) in the operators' coordinates (an inverse adds ``u_origin_v`` back)."""
        return (u_limits_v[0] - self.u_origin_v, u_limits_v[1] - self.u_origin_v)

    def in_model_direction(self, x_um) -> np.ndarray:
        """``x_um`` as the model was fitted (sign·x): what its inverses must reproduce."""
        return self.sign * np.asarray(x_um, dtype=float)

    # -- prediction -------------------------------------------------------------------
    def _require_thresholds(self):
        if self.thresholds_v is None:
            raise RuntimeError(f"{self.name} model has no thresholds yet: fit it or give thresholds_v")

    def _require_fitted(self):
        if self.weights_um_per_v is None:
            raise RuntimeError(f"{self.name} model is not fitted")

    def predict(self, u_v, sample_rate_hz=None, du_v_per_s=None, ddu_v_per_s2=None) -> np.ndarray:
        """Displacement (µm) for a drive (Series or array of V), from relaxed operators."""
        self._require_fitted()
        signal = Signal(u_v, sample_rate_hz, du_v_per_s, ddu_v_per_s2)
        x = np.zeros(signal.u_v.size)
        for blk in self.blocks(signal):
            x += blk.columns @ np.atleast_1d(getattr(self, blk.name))
        return self.sign * x

    # -- serialisation ----------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-serialisable parameters (floats round-trip exactly through json)."""
        self._require_fitted()
        out = {"model": self.name, "thresholds_v": self.thresholds_v.tolist(),
               "train_rms_um": self.train_rms_um, "sign": self.sign}
        if self.u_origin_v:
            out["u_origin_v"] = self.u_origin_v
        out.update({k: getattr(self, k) for k in self._config_names})
        for key in self._param_names:
            val = getattr(self, key)
            out[key] = val.tolist() if isinstance(val, np.ndarray) else float(val)
        return out

    @classmethod
    def from_dict(cls, d: dict) -> "HysteresisModel":
        if d.get("model") != cls.name:
            raise ValueError(f"expected model {cls.name!r}, got {d.get('model')!r}")
        model = cls(thresholds_v=d["thresholds_v"], **{k: d[k] for k in cls._config_names if k != "n_operators"})
        model.set_parameters({k: d[k] for k in cls._param_names})
        model.train_rms_um = d.get("train_rms_um")
        model.sign = float(d.get("sign", 1.0))
        model.u_origin_v = float(d.get("u_origin_v", 0.0))
        return model

    def __repr__(self) -> str:
        state = "fitted" if self.weights_um_per_v is not None else "unfitted"
        return f"{type(self).__name__}(n_operators={self.n_operators}, {state})"
