"""What the paper's PI family (static, dynamic, GRPI) shares: thresholds (eq. 9), the
linear-in-parameters fit over design blocks, prediction, validation, JSON round trips and the
rest of the model contract (service.science.models.contract).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import ClassVar

import numpy as np

from service.science.data.record import Record, as_record_list, finite_array
from service.science.data.signals import sensitivity_sign
from service.science.fitting.lsq import Block, design_matrix, solve_blocks, stack_blocks
from service.science.fitting.validation import evaluate_records, max_of
from service.science.models.contract import UNBOUNDED_V, Drive, split_stored

#: what an identification of the PI family holds out (the stored metrics say it in words)
HELD_OUT_NOTE = (
    "last ceil(20 %) of the full cycles of every block (last 20 % of samples where a block has "
    "no cycles); means are over blocks"
)


def equal_thresholds(u_max_v: float, n_operators: int) -> np.ndarray:
    """Eq. 9: n thresholds equally spaced from 0 below max(u)/2 (120 V, n=10 → 0, 6, …, 54 V)."""
    if n_operators < 1:
        raise ValueError(f"n_operators must be at least 1, got {n_operators}")
    if not u_max_v > 0:
        raise ValueError(f"max(u_v) must be positive to place thresholds, got {u_max_v:g} V")
    return np.arange(n_operators) * (u_max_v / (2.0 * n_operators))


class HysteresisModel:
    """Base of the PI family. Subclasses define ``name``, ``_param_names``, ``blocks`` and ``inverse``.

    Configuration: ``n_operators``, ``thresholds_v`` (V; None: placed by eq. 9 over the fitted
    drive), ``fit_offset``. Learned state: ``thresholds_v``, ``u_origin_v``, ``sign``, the
    parameters in ``_param_names`` and ``train_rms_um``.
    """

    name: ClassVar[str] = ""
    rate_dependent: ClassVar[bool] = False
    judges_stroke: ClassVar[bool] = False  #: no flexure dynamics: a stroke verdict only warns
    #: the effects the model describes, hysteresis first (the composite discovery starts from)
    described_effects: ClassVar[tuple[str, ...]] = ("hysteresis",)
    _param_names: ClassVar[tuple[str, ...]] = ()
    _scalar_names: ClassVar[tuple[str, ...]] = ("offset_um",)
    _config_keys: ClassVar[tuple[str, ...]] = ("n_operators", "thresholds_v", "fit_offset")

    def __init__(self, n_operators: int = 10, thresholds_v=None, fit_offset: bool = True):
        given = None if thresholds_v is None else np.asarray(thresholds_v, dtype=float)
        self._config = {
            "n_operators": int(n_operators if given is None else len(given)),
            "thresholds_v": None if given is None else given.tolist(),
            "fit_offset": bool(fit_offset),
        }
        self.thresholds_v = None if given is None else given.copy()
        self.weights_um_per_v: np.ndarray | None = None
        self.offset_um = 0.0
        self.train_rms_um: float | None = None
        self.sign = 1.0  #: −1 when the gauge reads against the drive: fitted to −x, predicts −(…)
        #: the drive (V) the operators count from: 0 V, or the lowest drive of the fitted records when
        #: it went below 0 V (a bipolar or negative record); thresholds span the drive above it
        self.u_origin_v = 0.0

    # -- configuration ----------------------------------------------------------------
    def get_config(self) -> dict:
        """The constructor's arguments (JSON types); ``fit`` never changes them."""
        return copy.deepcopy(self._config)

    @property
    def n_operators(self) -> int:
        return self._config["n_operators"]

    @property
    def is_fitted(self) -> bool:
        return self.weights_um_per_v is not None

    @property
    def fit_offset(self) -> bool:
        return self._config["fit_offset"]

    @classmethod
    def for_effects(cls, effects: Sequence[str], n_operators: int = 10, parent=None):
        """This kind for an identification of ``effects``: the paper's models take only 'hysteresis'
        (an identification of the static PI with more fits the composite on it:
        service.science.discovery.registry.model_for)."""
        if set(effects) - {"hysteresis"}:
            raise ValueError(
                f"effects beyond 'hysteresis' build a composite model on a static PI; "
                f"model {cls.name!r} takes effects ['hysteresis'] only"
            )
        return cls(n_operators=n_operators)

    # -- the design -----------------------------------------------------------------
    def blocks(self, drive: Drive) -> list[Block]:
        """Design blocks for one drive (current nonlinear parameters)."""
        raise NotImplementedError

    def _offset_blocks(self, n: int) -> list[Block]:
        return [Block.make("offset_um", np.ones(n))] if self.fit_offset else []

    def design_blocks(self, record: Record) -> list[Block]:
        """Named column blocks with bounds for ``record``; stack further blocks to extend the fit."""
        self._require_thresholds()
        return self.blocks(Drive.of(record))

    def design_matrix(self, record: Record) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(A (n, p), lower (p,), upper (p,)) such that ``predict(record) = A @ parameters``."""
        return design_matrix(self.design_blocks(record))

    # -- fitting ----------------------------------------------------------------------
    def _prepare(self, data, row_weights=None) -> tuple[list[Record], np.ndarray, np.ndarray | None]:
        """(records, stacked x_um, row weights or None); places the thresholds.

        Without ``row_weights``, records with ``hold_out`` weight their training rows (of the
        blocks that drive their axis) 1 and every other row 0."""
        items = as_record_list(data)
        target = np.concatenate([s.require_x() for s in items])
        self.sign = sensitivity_sign(np.concatenate([s.u_v for s in items]), target)
        target = self.sign * target
        if row_weights is None and any(s.hold_out for s in items):
            row_weights = np.concatenate([s.training_mask(own_axis_only=True) for s in items]).astype(float)
            if not row_weights.any():
                raise ValueError("no training rows: every block is too short to hold out a cycle and keep one")
        if row_weights is not None:
            row_weights = finite_array("row_weights", row_weights)
            if row_weights.size != target.size:
                raise ValueError(f"the records have {target.size} samples but row_weights has {row_weights.size}")
            if np.any(row_weights < 0) or not np.any(row_weights > 0):
                raise ValueError("row_weights must be non-negative and not all zero")
        given = self._config["thresholds_v"]
        if given is None:
            self.u_origin_v = min(0.0, min(float(s.u_v.min()) for s in items))
            u_max_v = max(float(s.u_v.max()) for s in items)
            self.thresholds_v = equal_thresholds(u_max_v - self.u_origin_v, self.n_operators)
        else:
            self.u_origin_v, self.thresholds_v = 0.0, np.asarray(given, dtype=float)
        return items, target, row_weights

    def stacked_blocks(self, items: Sequence[Record]) -> list[Block]:
        return stack_blocks([self.blocks(Drive.of(s)) for s in items])

    def fit(self, data, row_weights=None) -> HysteresisModel:
        """Least squares over all records jointly, with each block's bounds; returns self.

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
        """Drive limits (V; None: unbounded) in the operators' coordinates (an inverse adds
        ``u_origin_v`` back)."""
        lo, hi = UNBOUNDED_V if u_limits_v is None else u_limits_v
        return (lo - self.u_origin_v, hi - self.u_origin_v)

    def in_model_direction(self, x_um) -> np.ndarray:
        """``x_um`` as the model was fitted (sign·x): what its inverses must reproduce."""
        return self.sign * np.asarray(x_um, dtype=float)

    # -- prediction, inversion, validation ----------------------------------------------
    def _require_thresholds(self):
        if self.thresholds_v is None:
            raise RuntimeError(f"{self.name} model has no thresholds yet: fit it or give thresholds_v")

    def _require_fitted(self):
        if self.weights_um_per_v is None:
            raise RuntimeError(f"{self.name} model is not fitted")

    def predict(self, drive, sample_rate_hz: float | None = None) -> np.ndarray:
        """Displacement (µm) for a drive (Record, or array of V at ``sample_rate_hz``), from
        relaxed operators."""
        self._require_fitted()
        d = Drive.of(drive, sample_rate_hz)
        x = np.zeros(d.n_samples)
        for blk in self.blocks(d):
            x += blk.columns @ np.atleast_1d(getattr(self, blk.name))
        return self.sign * x

    def inverse(self, x_ref_um, *, sample_rate_hz: float | None = None, u_limits_v=None) -> np.ndarray:
        """Voltage (V) whose prediction follows ``x_ref_um`` (µm) from relaxed operators."""
        raise NotImplementedError

    def stack_demand_um(self, x_ref_um, sample_rate_hz: float | None = None) -> np.ndarray:
        """The reference itself (µm): the PI family has no dynamics after the stack."""
        return np.array(x_ref_um, dtype=float)

    def evaluate(self, records) -> dict:
        """Train/held-out RMS (µm) per block of the blocks that drive each record's axis, and their
        means over blocks (service.science.fitting.validation)."""
        records = as_record_list(records)
        return evaluate_records(records, [self.predict(r) for r in records], own_axis_only=True)

    def validate(self, records) -> dict:
        """``evaluate`` plus the largest train and held-out error (µm) over blocks."""
        ev = self.evaluate(records)
        blocks = [b for d in ev["per_dataset"] for b in d["blocks"]]
        return {
            **ev,
            "train_max_abs_um": max_of(blocks, "train"),
            "validation_max_abs_um": max_of(blocks, "validation"),
            "held_out": HELD_OUT_NOTE,
        }

    # -- serialisation ----------------------------------------------------------------
    def to_dict(self) -> dict:
        """``{"model", "config", **learned state}``, JSON-serialisable (floats round-trip exactly)."""
        self._require_fitted()
        out = {
            "model": self.name,
            "config": self.get_config(),
            "thresholds_v": self.thresholds_v.tolist(),
            "u_origin_v": self.u_origin_v,
            "sign": self.sign,
            "train_rms_um": self.train_rms_um,
        }
        for key in self._param_names:
            val = getattr(self, key)
            out[key] = val.tolist() if isinstance(val, np.ndarray) else float(val)
        return out

    @classmethod
    def from_dict(cls, d: dict) -> HysteresisModel:
        config, state = split_stored(d, cls.name, cls._config_keys)
        model = cls(**{k: config[k] for k in cls._config_keys if k in config})
        model.thresholds_v = np.asarray(state["thresholds_v"], dtype=float)
        model.set_parameters({k: state[k] for k in cls._param_names})
        model.train_rms_um = state.get("train_rms_um")
        model.sign = float(state.get("sign", 1.0))
        model.u_origin_v = float(state.get("u_origin_v", 0.0))
        return model

    def __repr__(self) -> str:
        state = "fitted" if self.weights_um_per_v is not None else "unfitted"
        return f"{type(self).__name__}(n_operators={self.n_operators}, {state})"
