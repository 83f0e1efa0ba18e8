"""The composite model: static PI hysteresis plus an ordered list of effects, fitted jointly.

x̂ = T_k(…T_1([P(u) | 1 | effect columns]) …) · c, where P are play-operator outputs (weights ≥ 0),
effect columns are additive regressors and T are transforms (delay, resonance) with a few
nonlinear parameters. The weights c solve one bounded least-squares problem on the training
rows; each transform's parameters are found by an outer search on the current prediction
(separable least squares: linear weights exact, nonlinear ones searched), alternated twice.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from service.science.effects import EFFECTS, RecordContext, ordered
from service.science.effects.harmonics import harmonic_data
from service.science.effects.operators import OPERATOR_FACTOR
from service.science.models.base import equal_thresholds
from service.science.data.signals import sensitivity_sign
from service.science.models.kernels import play_operators
from service.science.fitting.lsq import Block, solve_blocks
from service.science.discovery.records import Record
from service.science.fitting.validation import evaluate_record, mean_of

OUTER_ITERATIONS = 2


class CompositeModel:
    """``effects`` names (registry order is applied), ``n_operators`` base play operators."""

    name = "composite"

    def __init__(self, effects: Sequence[str] = (), n_operators: int = 10):
        unknown = [e for e in effects if e not in EFFECTS and e != "hysteresis"]
        if unknown:
            raise ValueError(f"unknown effects {unknown}; known: {', '.join(EFFECTS)}")
        self.effects = ordered(effects)
        self.n_operators = int(n_operators)
        self.thresholds_v = None
        self.theta: dict[str, dict] = {}
        self.coef: dict[str, np.ndarray] | None = None
        self.scales: dict = {}
        self.train_rms_um = None
        self.sign = 1.0          #: −1 when the gauge reads against the drive (see sensitivity_sign)

    # -- design -------------------------------------------------------------------------
    @property
    def transforms(self) -> list[str]:
        return [e for e in self.effects if EFFECTS[e].stage == "transform"]

    def _context(self, rec: Record) -> RecordContext:
        return self.context(rec.u_v, rec.fs_hz, rec.du, rec.ddu, rec.u_other_v, rec.x_other_um)

    def context(self, u_v: np.ndarray, fs_hz: float, du: np.ndarray, ddu: np.ndarray,
                u_other_v: np.ndarray | None = None, x_other_um: np.ndarray | None = None) -> RecordContext:
        """What the effects see of a drive ``u_v`` (V) at ``fs_hz``, with this model's thresholds and
        scales (so every effect block has the width its fitted weights have)."""
        origin = self.u_origin_v
        u_v = u_v - origin
        u_other_v = None if u_other_v is None else u_other_v - origin
        p = play_operators(u_v, self.thresholds_v)
        p_other = None if u_other_v is None else play_operators(u_other_v, self.thresholds_v)
        time_scale_s = self.scales.get("time_scale_s")
        if time_scale_s is None:
            raise ValueError("this composite model was stored before its time scale was kept: refit it "
                             "(POST /api/models/{id}/refine with its own effects)")
        return RecordContext(u_v, fs_hz, p, du, ddu, u_other_v, p_other, self.scales["min_period_s"],
                             1.0 / self.scales["min_period_s"], self.scales["u_scale_v"], time_scale_s, x_other_um)

    def raw_blocks(self, rec: Record) -> list[Block]:
        """Hysteresis, offset and additive effect blocks of one record (before transforms)."""
        ctx = self._context(rec)
        out = [Block.make("weights_um_per_v", ctx.p, lower=0.0), Block.make("offset_um", np.ones(rec.n))]
        for name in self.effects:
            out += EFFECTS[name].blocks(ctx)
        return out

    def _transform(self, columns: np.ndarray, fs_hz: float, theta: dict, skip: str | None = None) -> np.ndarray:
        for name in self.transforms:
            if name != skip and name in theta:
                columns = EFFECTS[name].apply(columns, fs_hz, theta[name])
        return columns

    # -- fitting ------------------------------------------------------------------------
    @property
    def u_origin_v(self) -> float:
        """The drive (V) the model's operators count from: 0 V, or the lowest drive of the fitted
        records if it went below 0 V (a bipolar or negative amplifier input)."""
        return float(self.scales.get("u_origin_v", 0.0))

    def _setup(self, records: Sequence[Record]) -> None:
        origin = min(0.0, min(float(np.min(r.u_v)) for r in records))
        u_max = max(float(np.max(r.u_v)) for r in records) - origin
        n = self.n_operators * (OPERATOR_FACTOR if "operators" in self.effects else 1)
        self.thresholds_v = equal_thresholds(u_max, n)
        self.scales = {"u_origin_v": origin, "u_scale_v": max(float(np.max(np.abs(r.u_v - origin))) for r in records),
                       "min_period_s": min(r.min_period_s() for r in records),
                       "time_scale_s": max(r.n / r.fs_hz for r in records)}

    def fit(self, records: Sequence[Record], fixed_theta: dict | None = None,
            exclude_frequency_hz: float | None = None) -> "CompositeModel":
        """Fit on the training rows of ``records`` (decimated slow cycles). Transforms named in
        ``fixed_theta`` keep those parameters (a warm start: only the others are searched)."""
        fixed_theta = fixed_theta or {}
        records = list(records)
        self._setup(records)
        self._fs = records[0].fs_hz
        raw = [self.raw_blocks(r) for r in records]
        names = [b.name for b in raw[0]]
        widths = [b.width for b in raw[0]]
        lower = [b.lower for b in raw[0]]
        upper = [b.upper for b in raw[0]]
        a_raw = [np.hstack([b.columns for b in blocks]) for blocks in raw]
        rows = [r.fit_rows(exclude_frequency_hz) for r in records]
        target = np.concatenate([r.x_um[i] for r, i in zip(records, rows)])
        self.sign = sensitivity_sign(np.concatenate([r.u_v[i] for r, i in zip(records, rows)]), target)
        target = self.sign * target    # fitted in the actuator's own direction (bounded weights ≥ 0)

        def solve(theta, exact: str | None = None):
            """Weights for ``theta``; ``exact`` names a row-local transform applied at the rows only
            (after the others, which commute with it)."""
            parts = []
            for k, r in enumerate(records):
                if exact is None:
                    parts.append(self._transform(a_raw[k], r.fs_hz, theta)[rows[k]])
                else:
                    if k not in cache:
                        cache[k] = self._transform(a_raw[k], r.fs_hz, theta, skip=exact)
                    base = cache[k]
                    parts.append(EFFECTS[exact].apply_rows(base, r.fs_hz, theta[exact], rows[k]))
            a = np.vstack(parts)
            splits = np.cumsum([0] + widths)
            blocks = [Block(nm, (a[:, splits[j]:splits[j + 1]],), lower[j], upper[j]) for j, nm in enumerate(names)]
            return solve_blocks(blocks, target)

        theta = {name: dict(fixed_theta.get(name) or self._identity_theta(name)) for name in self.transforms}
        free = [name for name in self.transforms if name not in fixed_theta]
        sol = solve(theta)
        for it in range(OUTER_ITERATIONS if free else 0):
            last = it == OUTER_ITERATIONS - 1
            for name in free:
                if EFFECTS[name].row_local:
                    cache: dict = {}
                    theta[name] = self._grid_refine(name, lambda th: solve({**theta, name: th}, exact=name).rms)
                else:  # harmonics with every weight refitted (already fine), else a grid on the
                    # current prediction refined with the exact cost
                    best = self._harmonic_search(name, a_raw, records, theta)
                    exact_cost = lambda th: solve({**theta, name: th}).rms  # noqa: E731
                    if best is None:
                        z = [self._transform(a_raw[k] @ sol.coef, r.fs_hz, theta, skip=name)
                             for k, r in enumerate(records)]
                        best = self._search(name, z, records, rows, target)
                        best = EFFECTS[name].refine(best, exact_cost) if last else best
                    elif last:  # the harmonics ignore bounds and transients: a last exact polish
                        best = EFFECTS[name].refine(best, exact_cost, fine=True)
                    theta[name] = best
            sol = solve(theta)
        self.theta = theta
        splits = np.cumsum([0] + widths)
        self.coef = {nm: sol.coef[splits[j]:splits[j + 1]].copy() for j, nm in enumerate(names)}
        self.train_rms_um = sol.rms
        return self

    def _identity_theta(self, name: str) -> dict:
        return {"delay_s": 0.0} if name == "delay" else {"fn_hz": 1e12, "zeta": 1.0}

    def _harmonic_search(self, name, a_raw, records, theta) -> dict | None:
        """A transform's parameters from the periodic blocks' harmonics (None if it has no such
        search or the data has too few periodic blocks)."""
        eff = EFFECTS[name]
        if not hasattr(eff, "harmonic_search"):
            return None
        columns = [self._transform(a, r.fs_hz, theta, skip=name) for a, r in zip(a_raw, records)]
        return eff.harmonic_search(harmonic_data(records, columns), records[0].fs_hz,
                                   1.0 / self.scales["min_period_s"])

    def _search(self, name, z, records, rows, target) -> dict:
        """Best parameters of one transform for the current prediction ``z`` (gain and offset free)."""
        eff = EFFECTS[name]

        def cost(th):
            col = np.concatenate([eff.apply(zk[:, None], r.fs_hz, th)[rows[k], 0] for k, (zk, r) in
                                  enumerate(zip(z, records))])
            a = np.column_stack([col, np.ones_like(col)])
            coef, *_ = np.linalg.lstsq(a, target, rcond=None)
            return float(np.sum((target - a @ coef) ** 2))

        return self._grid_refine(name, cost, records[0].fs_hz)

    def _grid_refine(self, name, cost, fs_hz=None) -> dict:
        eff = EFFECTS[name]
        fs = fs_hz or self._fs
        grid = eff.grid(fs, self.scales["min_period_s"], 1.0 / self.scales["min_period_s"])
        costs = [cost(th) for th in grid]
        return eff.refine(grid[int(np.argmin(costs))], cost)

    # -- prediction and validation ----------------------------------------------------------
    def predict(self, rec: Record) -> np.ndarray:
        if self.coef is None:
            raise RuntimeError("composite model is not fitted")
        blocks = self.raw_blocks(rec)
        a = np.hstack([b.columns for b in blocks])
        c = np.concatenate([self.coef[b.name] for b in blocks])
        return self.sign * (self._transform(a, rec.fs_hz, self.theta) @ c)

    def evaluate(self, records: Sequence[Record]) -> dict:
        """Train/held-out metrics per dataset and their means over blocks (service.science.fitting.validation)."""
        per, blocks = [], []
        for r in records:
            fig = evaluate_record(r.x_um, self.predict(r), r.splits)
            per.append({"dataset_id": r.label, **fig})
            blocks += fig["blocks"]
        return {"train_rms_um": mean_of(blocks, "train"), "validation_rms_um": mean_of(blocks, "validation"),
                "per_dataset": per}

    def n_parameters(self) -> int:
        return int(sum(v.size for v in (self.coef or {}).values()) + sum(len(t) for t in self.theta.values()))

    def describe(self) -> dict:
        """Fitted effect parameters in words, per effect."""
        return {e: EFFECTS[e].describe(self.theta.get(e, {}), self.coef or {}) for e in self.effects}

    # -- serialisation -----------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {"model": self.name, "effects": ["hysteresis"] + self.effects, "n_operators": self.n_operators,
                "thresholds_v": self.thresholds_v.tolist(), "scales": self.scales,
                "theta": self.theta, "coef": {k: v.tolist() for k, v in self.coef.items()},
                "train_rms_um": self.train_rms_um, "sign": self.sign}

    @classmethod
    def from_dict(cls, d: dict) -> "CompositeModel":
        m = cls(d["effects"], d["n_operators"])
        m.thresholds_v = np.asarray(d["thresholds_v"], dtype=float)
        m.scales, m.theta = dict(d["scales"]), {k: dict(v) for k, v in d["theta"].items()}
        m.coef = {k: np.asarray(v, dtype=float) for k, v in d["coef"].items()}
        m.train_rms_um = d.get("train_rms_um")
        m.sign = float(d.get("sign", 1.0))
        return m


def fit_composite(records, effects, n_operators: int = 10, warm_theta: dict | None = None) -> CompositeModel:
    """Fit ``hysteresis + effects``; with ``warm_theta`` (a parent model's transform parameters)
    also fit with those kept and return whichever of the two fits the training rows better."""
    full = CompositeModel(effects, n_operators).fit(records)
    warm = {k: v for k, v in (warm_theta or {}).items() if k in full.transforms}
    if not warm:
        return full
    kept = CompositeModel(effects, n_operators).fit(records, fixed_theta=warm)
    return kept if kept.train_rms_um < full.train_rms_um else full


def held_out_frequency_metrics(records, effects, n_operators: int = 10, theta: dict | None = None) -> dict:
    """Leave one frequency out: fit on every other frequency's training cycles, score the whole
    blocks at that frequency (µm). ``theta`` fixes the transforms (as fitted on all data)."""
    freqs = sorted({s.block.get("frequency_hz") for r in records for s in r.splits if s.block.get("frequency_hz")})
    per = []
    if len(freqs) < 2:
        return {"validation_rms_um": None, "per_frequency": [], "note": "fewer than two frequencies"}
    for f in freqs:
        m = CompositeModel(effects, n_operators).fit(records, fixed_theta=theta, exclude_frequency_hz=f)
        errs = []
        for r in records:
            res = r.x_um - m.predict(r)
            errs += [float(np.sqrt(np.mean(res[s.train[0]:s.held_out[1]] ** 2))) for s in r.splits
                     if s.block.get("frequency_hz") == f]
        per.append({"frequency_hz": f, "validation_rms_um": float(np.mean(errs))})
    return {"validation_rms_um": float(np.mean([p["validation_rms_um"] for p in per])), "per_frequency": per}

