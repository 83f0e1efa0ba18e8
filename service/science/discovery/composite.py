"""The composite model: static PI hysteresis plus an ordered list of effects, fitted jointly.

x̂ = T_k(…T_1([P(u) | 1 | effect columns]) …) · c, where P are play-operator outputs (weights ≥ 0),
effect columns are additive regressors and T are transforms (delay, resonance) with a few
nonlinear parameters. The weights c solve one bounded least-squares problem on the training
rows; each transform's parameters are found by an outer search on the current prediction
(separable least squares: linear weights exact, nonlinear ones searched: composite_fit.py), alternated
twice.

It satisfies the model contract (service.science.models.contract): configuration in the constructor,
``fit(records)``, ``predict(drive)``, ``inverse`` (service.science.discovery.composite_inverse), the
stroke check's ``stack_demand_um`` and JSON round trips.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import numpy as np

from service.science.data.record import Record, as_record_list, finite_array
from service.science.data.signals import drive_derivatives
from service.science.discovery.column_memo import effect_blocks, play_outputs, shared_effect_columns
from service.science.discovery.composite_fit import FitProblem, TransformSearch, remembered
from service.science.discovery.composite_inverse import (
    COMPOSITE_LIMITS_V,
    FIXED_POINT_ITERATIONS,
    composite_inverse,
    invert_transforms,
)
from service.science.effects import EFFECTS, RecordContext, ordered
from service.science.effects.sensor_nonlinearity import OUTPUT_ROUNDS
from service.science.fitting.lsq import Block
from service.science.fitting.metrics import rms
from service.science.fitting.validation import evaluate_records, max_of
from service.science.models.base import equal_thresholds
from service.science.models.contract import Drive, split_stored

#: what an identification of a composite holds out (the stored metrics say it in words)
HELD_OUT_NOTE = (
    "last ceil(20 %) of the full cycles of every block; means are over blocks. "
    "The held-out-frequency figures: each frequency left out of the fit in turn"
)


#: the records' fastest drive rate, for a drive stage's grid: this percentile of every sample's rate (the
#: few samples of a step are left out; a 100 Hz block's steepest stretch is kept)
FASTEST_RATE_PERCENTILE = 99.95


class CompositeModel(TransformSearch):
    """Configuration: ``effects`` names (registry order is applied; 'hysteresis' is the base),
    ``n_operators`` base play operators, ``fixed_theta`` transform parameters kept as given (only
    the others are searched), ``exclude_frequency_hz`` blocks left out of the fit, ``warm_theta`` a
    parent model's transform parameters (the fit also tries them kept and keeps the better),
    ``local_theta`` parameters found on another model from which the free transforms are only
    refined (the effect's local search, not its grid: a diagnosis's candidate on the flexible base).
    Learned state: ``thresholds_v``, ``scales``, ``theta``, ``coef``, ``sign``, ``train_rms_um``."""

    name = "composite"
    judges_stroke = True  #: it models the flexure after the stack: its stroke verdict is a refusal

    def __init__(
        self,
        effects: Sequence[str] = (),
        n_operators: int = 10,
        *,
        fixed_theta: dict | None = None,
        exclude_frequency_hz: float | None = None,
        warm_theta: dict | None = None,
        local_theta: dict | None = None,
    ):
        unknown = [e for e in effects if e not in EFFECTS and e != "hysteresis"]
        if unknown:
            raise ValueError(f"unknown effects {unknown}; known: {', '.join(EFFECTS)}")
        self._config = {
            "effects": ordered(effects),
            "n_operators": int(n_operators),
            "fixed_theta": copy.deepcopy(fixed_theta) or None,
            "exclude_frequency_hz": None if exclude_frequency_hz is None else float(exclude_frequency_hz),
            "warm_theta": copy.deepcopy(warm_theta) or None,
            "local_theta": copy.deepcopy(local_theta) or None,
        }
        self.thresholds_v = None
        self.theta: dict[str, dict] = {}
        self.coef: dict[str, np.ndarray] | None = None
        self.scales: dict = {}
        self.train_rms_um = None
        self.sign = 1.0  #: −1 when the gauge reads against the drive (see sensitivity_sign)

    # -- configuration ------------------------------------------------------------------
    def get_config(self) -> dict:
        """The constructor's arguments (JSON types); ``fit`` never changes them."""
        return copy.deepcopy(self._config)

    @property
    def effects(self) -> list[str]:
        """The effects beyond hysteresis, in registry order."""
        return list(self._config["effects"])

    @property
    def n_operators(self) -> int:
        return self._config["n_operators"]

    @property
    def is_fitted(self) -> bool:
        return self.coef is not None

    @classmethod
    def for_effects(cls, effects: Sequence[str], n_operators: int = 10, parent=None) -> CompositeModel:
        """Hysteresis + ``effects``, warm-started at ``parent``'s transforms when it has any."""
        warm = as_composite(parent).theta if parent is not None else None
        return cls(effects, n_operators, warm_theta=warm)

    @property
    def described_effects(self) -> tuple[str, ...]:
        """The effects the model describes, hysteresis first (the model contract's member)."""
        return ("hysteresis", *self.effects)

    # -- design -------------------------------------------------------------------------
    @property
    def transforms(self) -> list[str]:
        return [e for e in self.effects if EFFECTS[e].stage == "transform"]

    @property
    def drive_stages(self) -> list[str]:
        """The effects that map the drive before everything else (the amplifier's rate limit)."""
        return [e for e in self.effects if EFFECTS[e].stage == "drive"]

    def _context(self, drive: Drive) -> RecordContext:
        du, ddu = drive.derivatives()
        return self.context(drive.u_v, drive.require_rate(), du, ddu, drive.u_other_v, drive.x_other_um, drive.temp_c)

    def staged_drive(self, u_v: np.ndarray, sample_rate_hz: float) -> np.ndarray:
        """The drive (V) the stack sees for the planned ``u_v`` (V): through every drive stage fitted."""
        for name in self.drive_stages:
            if name in self.theta:
                u_v = EFFECTS[name].drive(u_v, sample_rate_hz, self.theta[name])
        return u_v

    def context(
        self,
        u_v: np.ndarray,
        sample_rate_hz: float,
        du: np.ndarray,
        ddu: np.ndarray,
        u_other_v: np.ndarray | None = None,
        x_other_um: np.ndarray | None = None,
        temp_c: np.ndarray | None = None,
    ) -> RecordContext:
        """What the effects see of a drive ``u_v`` (V) at ``sample_rate_hz``, with this model's thresholds and
        scales (so every effect block has the width its fitted weights have); the drive stages first."""
        if any(name in self.theta for name in self.drive_stages):
            u_v = self.staged_drive(u_v, sample_rate_hz)
            du, ddu = drive_derivatives(u_v, sample_rate_hz)
        origin = self.u_origin_v
        p = play_outputs(u_v, origin, self.thresholds_v)
        p_other = None if u_other_v is None else play_outputs(u_other_v, origin, self.thresholds_v)
        u_v = u_v - origin
        u_other_v = None if u_other_v is None else u_other_v - origin
        time_scale_s = self.scales.get("time_scale_s")
        if time_scale_s is None:
            raise ValueError(
                "this composite model was stored before its time scale was kept: refit it "
                "(POST /api/models/{id}/refine with its own effects)"
            )
        temp_ref = self.scales.get("temp_ref_c")
        temp_dev = None if temp_c is None or temp_ref is None else np.asarray(temp_c, dtype=float) - temp_ref
        return RecordContext(
            u_v,
            sample_rate_hz,
            p,
            du,
            ddu,
            u_other_v,
            p_other,
            self.scales["min_period_s"],
            1.0 / self.scales["min_period_s"],
            self.scales["u_scale_v"],
            time_scale_s,
            x_other_um,
            temp_dev,
            learned=self.scales.get("learned", {}),
        )

    def raw_blocks(self, drive: Drive) -> list[Block]:
        """Hysteresis, offset and additive effect blocks of one drive (before transforms); within a
        ``shared_effect_columns`` scope each effect's blocks are built once per record context."""
        ctx = self._context(drive)
        sources = (drive.u_v, drive.u_other_v, drive.x_other_um, drive.temp_c, ctx.du, ctx.ddu)
        params = (
            ctx.fs_hz,
            self.u_origin_v,
            np.asarray(self.thresholds_v, dtype=float).tobytes(),
            repr(sorted(self.scales.items())),
            repr([self.theta.get(name) for name in self.drive_stages]),
        )
        out = [Block.make("weights_um_per_v", ctx.p, lower=0.0), Block.make("offset_um", np.ones(ctx.n))]
        for name in self.effects:
            out += effect_blocks(sources, (name, *params), lambda name=name: EFFECTS[name].blocks(ctx))
        return out

    def _transform(
        self, columns: np.ndarray, sample_rate_hz: float, theta: dict, skip: str | None = None
    ) -> np.ndarray:
        for name in self.transforms:
            if name != skip and name in theta:
                columns = EFFECTS[name].apply(columns, sample_rate_hz, theta[name])
        return columns

    def _transform_rows(
        self, columns: np.ndarray, sample_rate_hz: float, theta: dict, rows, skip: str | None = None
    ) -> np.ndarray:
        """``_transform(...)[rows]``, the last transform evaluated at ``rows`` alone (the same numbers)."""
        names = [name for name in self.transforms if name != skip and name in theta]
        for name in names[:-1]:
            columns = EFFECTS[name].apply(columns, sample_rate_hz, theta[name])
        return (
            EFFECTS[names[-1]].apply_rows(columns, sample_rate_hz, theta[names[-1]], rows) if names else columns[rows]
        )

    # -- fitting ------------------------------------------------------------------------
    @property
    def u_origin_v(self) -> float:
        """The drive (V) the model's operators count from: 0 V, or the lowest drive of the fitted
        records if it went below 0 V (a bipolar or negative amplifier input)."""
        return float(self.scales.get("u_origin_v", 0.0))

    def _setup(self, records: Sequence[Record]) -> None:
        origin = min(0.0, min(float(np.min(r.u_v)) for r in records))
        u_max = max(float(np.max(r.u_v)) for r in records) - origin
        n = self.n_operators * max([EFFECTS[e].operator_factor for e in self.effects], default=1)
        self.thresholds_v = equal_thresholds(u_max, n)
        self.scales = {
            "u_origin_v": origin,
            "u_scale_v": max(float(np.max(np.abs(r.u_v - origin))) for r in records),
            "min_period_s": min(r.min_period_s() for r in records),
            "time_scale_s": max(r.n_samples / r.sample_rate_hz for r in records),
        }
        temps = [r.temp_c for r in records if getattr(r, "temp_c", None) is not None]
        if temps:
            self.scales["temp_ref_c"] = float(np.mean(np.concatenate(temps)))
        learned = {name: EFFECTS[name].setup(records) for name in self.effects}
        if any(learned.values()):
            self.scales["learned"] = {name: v for name, v in learned.items() if v}

    @shared_effect_columns()  # the warm-started second fit reuses the first's columns
    def fit(
        self, records, fixed_theta: dict | None = None, exclude_frequency_hz: float | None = None
    ) -> CompositeModel:
        """Fit on the training rows of ``records`` (every block's, decimated; held-out cycles left
        out when a record holds them out); returns self. ``fixed_theta`` and
        ``exclude_frequency_hz`` override the configuration's for this fit only (kept for callers
        that predate the contract: give them to the constructor)."""
        records = as_record_list(records)
        fixed = self._config["fixed_theta"] if fixed_theta is None else fixed_theta
        exclude = self._config["exclude_frequency_hz"] if exclude_frequency_hz is None else exclude_frequency_hz
        self._fit(records, fixed or {}, exclude)
        warm = {k: v for k, v in (self._config["warm_theta"] or {}).items() if k in self.transforms}
        if warm:
            kept = CompositeModel(self.effects, self.n_operators, exclude_frequency_hz=exclude)
            kept._fit(records, warm, exclude)
            if kept.train_rms_um < self.train_rms_um:
                for key in ("thresholds_v", "scales", "theta", "coef", "train_rms_um", "sign", "_fs"):
                    setattr(self, key, getattr(kept, key))
        return self

    def _fit(self, records: list[Record], fixed_theta: dict, exclude_frequency_hz: float | None) -> None:
        """Transforms named in ``fixed_theta`` keep those parameters (only the others are searched)."""
        self._setup(records)
        self._fs = records[0].sample_rate_hz
        self.theta = {n: dict(fixed_theta[n]) for n in self.drive_stages if n in fixed_theta}
        for name in self.drive_stages:
            if name not in fixed_theta:
                self.theta[name] = self._search_drive(records, name, fixed_theta, exclude_frequency_hz)
        drive_theta = dict(self.theta)
        problem = FitProblem(self, records, exclude_frequency_hz)
        self.sign = problem.sign
        free = [name for name in self.transforms if name not in fixed_theta]
        local = self._config["local_theta"] or {}
        if free and set(free) <= set(local):  # refined from where another model found them
            start = {name: fixed_theta.get(name) or local[name] for name in self.transforms}
            theta, sol = self._refine_locally(problem, free, start)
        else:
            theta, sol = self._search_transforms(problem, free, fixed_theta)
        self.theta = {**drive_theta, **theta}
        coef, train_rms, names, splits = self._fit_gauge(problem, theta, sol)
        self.coef = {nm: coef[splits[j] : splits[j + 1]].copy() for j, nm in enumerate(names)}
        self.train_rms_um = train_rms

    def _search_drive(self, records: list[Record], name: str, fixed_theta: dict, exclude_frequency_hz) -> dict:
        """A drive stage's parameters: its grid (from the records' fastest drive rate, V/s, the
        FASTEST_RATE_PERCENTILE of every sample's), then its
        refinement, each value costed by the weights' training RMS with the transforms as given or at
        identity (the columns rebuilt for each value)."""
        eff = EFFECTS[name]
        held = {t: dict(fixed_theta.get(t) or self._identity_theta(t)) for t in self.transforms}
        rates = np.concatenate([np.abs(np.diff(r.u_v)) * r.sample_rate_hz for r in records])
        fastest = float(np.percentile(rates, FASTEST_RATE_PERCENTILE))  # a step's jump is not a rate

        @remembered  # by the clamped value: the refinement re-asks for the grid's best
        def solved(th: dict) -> float:
            self.theta[name] = th
            return FitProblem(self, records, exclude_frequency_hz).solve(held).rms

        def cost(th: dict) -> float:
            return solved(eff.clamp(th, self._fs))

        grid = eff.grid(self._fs, self.scales["min_period_s"], fastest)
        costs = [cost(th) for th in grid]
        k = int(np.argmin(costs))
        bracket = (grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)])
        return eff.clamp(eff.refine(grid[k], cost, bracket=bracket), self._fs)

    def _fit_gauge(self, problem: FitProblem, theta: dict, sol):
        """The weights of ``sol`` and, when the model has an output effect (the gauge's bow), the bow
        fitted by alternating least squares, kept if a round beats no bow; (coef, train RMS µm, block
        names, column splits)."""
        gauge = self._output_effect()
        if gauge is None:
            return sol.coef, sol.rms, problem.names, problem.splits
        a, target, splits = problem.design(theta), problem.target, problem.splits
        self.scales["x_mid_um"] = float(0.5 * (target.max() + target.min()))
        self.scales["x_half_um"] = float(0.5 * (target.max() - target.min()))
        mid, half = self.scales["x_mid_um"], self.scales["x_half_um"]
        z = a @ sol.coef
        width = gauge.columns(z[:1], mid, half).shape[1]
        coef, train_rms = np.append(sol.coef, np.zeros(width)), sol.rms  # no bow at all, unless a round beats it
        for _ in range(OUTPUT_ROUNDS):
            sol = problem.solve_design(a, Block.make(gauge.block_name, gauge.columns(z, mid, half)))
            z = a @ sol.coef[: splits[-1]]  # the output before the gauge with the new weights,
            err = rms(target - z - gauge.columns(z, mid, half) @ sol.coef[splits[-1] :])  # read as predict does
            if err < train_rms:
                coef, train_rms = sol.coef, err
        return coef, train_rms, problem.names + [gauge.block_name], np.append(splits, splits[-1] + width)

    def _output_effect(self):
        """The effect that maps the model's output (the gauge's bow), or None."""
        return next((EFFECTS[e] for e in self.effects if EFFECTS[e].stage == "output"), None)

    def gauge_output(self, z_um: np.ndarray) -> np.ndarray:
        """What the gauge reads (µm, the model's own direction) for the output ``z_um`` before it."""
        gauge = self._output_effect()
        if gauge is None:
            return z_um
        bow = gauge.columns(z_um, self.scales["x_mid_um"], self.scales["x_half_um"])
        return z_um + bow @ self.coef[gauge.block_name]

    def undo_gauge(self, x_um: np.ndarray) -> np.ndarray:
        """The output before the gauge (µm, the model's own direction) that reads ``x_um``."""
        gauge = self._output_effect()
        if gauge is None:
            return x_um
        return gauge.invert(x_um, self.coef[gauge.block_name], self.scales["x_mid_um"], self.scales["x_half_um"])

    # -- prediction, inversion and validation ------------------------------------------------
    def _require_fitted(self):
        if self.coef is None:
            raise RuntimeError("composite model is not fitted")

    def predict(self, drive, sample_rate_hz: float | None = None) -> np.ndarray:
        """Displacement (µm) for a drive: a Record (its rates, other-axis drive and displacement are
        used) or an array of V at ``sample_rate_hz`` (other axis unknown: no coupling), from rest."""
        self._require_fitted()
        d = Drive.of(drive, sample_rate_hz)
        # the transforms (resonance filter, delay) are linear and act on every column alike, so the
        # weighted sum is formed first and transformed once: one column filtered, not every column
        stack_um = sum(b.columns @ self.coef[b.name] for b in self.raw_blocks(d))
        return self.sign * self.gauge_output(self._transform(stack_um[:, None], d.require_rate(), self.theta)[:, 0])

    def inverse(
        self,
        x_ref_um,
        *,
        sample_rate_hz: float | None = None,
        u_limits_v=None,
        iterations: int = FIXED_POINT_ITERATIONS,
    ) -> np.ndarray:
        """The drive (V) whose prediction follows the planned reference ``x_ref_um`` (µm; starts and
        ends at rest), the PI inverse searched within ``u_limits_v`` (V; None: −60…180 V, beyond the
        stack's range so that a safety check sees what is needed). service.science.discovery.composite_inverse."""
        self._require_fitted()
        if not sample_rate_hz:
            raise ValueError("sample_rate_hz is needed to invert a composite model's dynamics")
        return composite_inverse(
            self,
            finite_array("x_ref_um", x_ref_um),
            float(sample_rate_hz),
            iterations,
            COMPOSITE_LIMITS_V if u_limits_v is None else u_limits_v,
        )

    def stack_demand_um(self, x_ref_um, sample_rate_hz: float | None = None) -> np.ndarray:
        """What the stack (hysteresis and additive effects) must deliver before the model's linear
        transforms for the output to follow the planned reference ``x_ref_um`` (µm)."""
        if not sample_rate_hz:
            raise ValueError("sample_rate_hz is needed to undo a composite model's dynamics")
        x_um = self.sign * self.undo_gauge(self.sign * np.asarray(x_ref_um, dtype=float))
        return invert_transforms(self, x_um, float(sample_rate_hz))

    def evaluate(self, records) -> dict:
        """Train/held-out metrics per dataset over every block (also those that drive only the other
        axis) and their means over blocks (service.science.fitting.validation)."""
        records = as_record_list(records)
        return evaluate_records(records, [self.predict(r) for r in records])

    @shared_effect_columns()  # the held-out frequencies' refits share the columns
    def validate(self, records) -> dict:
        """``evaluate``, the held-out frequencies (each left out of a refit in turn) and the largest
        train and held-out error (µm) over blocks, as every model family gives it (models/base.py)."""
        records = as_record_list(records)
        ev = self.evaluate(records)
        ev["held_out_frequencies"] = held_out_frequency_metrics(records, self.effects, self.n_operators, self.theta)
        blocks = [b for d in ev["per_dataset"] for b in d["blocks"]]
        return {
            **ev,
            "train_max_abs_um": max_of(blocks, "train"),
            "validation_max_abs_um": max_of(blocks, "validation"),
            "held_out": HELD_OUT_NOTE,
        }

    def n_parameters(self) -> int:
        return int(sum(v.size for v in (self.coef or {}).values()) + sum(len(t) for t in self.theta.values()))

    def describe(self) -> dict:
        """Fitted effect parameters in words, per effect."""
        return {e: EFFECTS[e].describe(self.theta.get(e, {}), self.coef or {}) for e in self.effects}

    # -- serialisation -----------------------------------------------------------------------
    def to_dict(self) -> dict:
        """``{"model", "config", **learned state}``, JSON-serialisable (floats round-trip exactly)."""
        self._require_fitted()
        return {
            "model": self.name,
            "config": self.get_config(),
            "thresholds_v": self.thresholds_v.tolist(),
            "scales": self.scales,
            "theta": self.theta,
            "coef": {k: v.tolist() for k, v in self.coef.items()},
            "train_rms_um": self.train_rms_um,
            "sign": self.sign,
        }

    @classmethod
    def from_dict(cls, d: dict) -> CompositeModel:
        config, d = split_stored(d, cls.name, ("effects", "n_operators"))
        m = cls(**config)
        m.thresholds_v = np.asarray(d["thresholds_v"], dtype=float)
        m.scales, m.theta = dict(d["scales"]), {k: dict(v) for k, v in d["theta"].items()}
        m.coef = {k: np.asarray(v, dtype=float) for k, v in d["coef"].items()}
        m.train_rms_um = d.get("train_rms_um")
        m.sign = float(d.get("sign", 1.0))
        return m


def as_composite(model) -> CompositeModel:
    """The composite model discovery starts from: ``model`` itself if it is one, else hysteresis +
    the effects ``model`` describes (``described_effects``: the dynamic PI's rate dependence), unfitted."""
    if isinstance(model, CompositeModel):
        return model
    return CompositeModel(list(model.described_effects[1:]), model.n_operators)


def fit_composite(records, effects, n_operators: int = 10, warm_theta: dict | None = None) -> CompositeModel:
    """Fit ``hysteresis + effects``; with ``warm_theta`` (a parent model's transform parameters)
    also fit with those kept and return whichever of the two fits the training rows better."""
    return CompositeModel(effects, n_operators, warm_theta=warm_theta).fit(records)


def held_out_frequency_metrics(records, effects, n_operators: int = 10, theta: dict | None = None) -> dict:
    """Leave one frequency out: fit on every other frequency's training cycles, score the whole
    blocks at that frequency (µm). ``theta`` fixes the transforms (as fitted on all data)."""
    freqs = sorted({s.block.get("frequency_hz") for r in records for s in r.splits if s.block.get("frequency_hz")})
    per = []
    if len(freqs) < 2:
        return {"validation_rms_um": None, "per_frequency": [], "note": "fewer than two frequencies"}
    for f in freqs:
        m = CompositeModel(effects, n_operators, fixed_theta=theta, exclude_frequency_hz=f).fit(records)
        errs = []
        for r in records:
            res = r.x_um - m.predict(r)
            errs += [rms(res[s.train[0] : s.held_out[1]]) for s in r.splits if s.block.get("frequency_hz") == f]
        per.append({"frequency_hz": f, "validation_rms_um": float(np.mean(errs))})
    return {"validation_rms_um": float(np.mean([p["validation_rms_um"] for p in per])), "per_frequency": per}
