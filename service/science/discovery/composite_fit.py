"""The composite model's fit (service.science.discovery.composite): the fit problem (the training
rows' design for a set of transform parameters, and the bounded least-squares solve over it) and
the searches for the transforms' nonlinear parameters (delay, resonance, …).

The raw columns (play operators, offset, effect columns) are built once per fit; a transform
(filter, delay) is applied to them for each ``theta`` tried. Pure numpy: no store, no HTTP.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.optimize import minimize

from service.science.data.record import Record
from service.science.data.signals import sensitivity_sign
from service.science.effects import EFFECTS
from service.science.effects.base import sum_of_taps
from service.science.effects.harmonics import harmonic_data
from service.science.fitting.lsq import Block, solve_blocks
from service.science.models.contract import Drive


class FitProblem:
    """The training rows of ``records`` for ``model`` (thresholds and scales already set):
    ``a_raw`` (per record: every sample when transforms need them, else the training rows),
    ``rows`` (per record: the rows ``a_raw`` is read at), ``target`` (µm, in the actuator's own
    direction, ``sign``), and the blocks' ``names``, bounds and column ``splits``."""

    def __init__(self, model, records: Sequence[Record], exclude_frequency_hz: float | None):
        self.model, self.records = model, list(records)
        raw = [model.raw_blocks(Drive.of(r)) for r in records]
        self.names = [b.name for b in raw[0]]
        self.lower = [b.lower for b in raw[0]]
        self.upper = [b.upper for b in raw[0]]
        self.splits = np.cumsum([0] + [b.width for b in raw[0]])
        rows = [r.fit_rows(exclude_frequency_hz) for r in records]
        target = np.concatenate([r.require_x()[i] for r, i in zip(records, rows)])
        self.sign = sensitivity_sign(np.concatenate([r.u_v[i] for r, i in zip(records, rows)]), target)
        if model.transforms:  # the transforms (filters, delays) need every sample of every column
            self.a_raw = [np.hstack([b.columns for b in blocks]) for blocks in raw]
        else:  # only the training rows are ever read
            self.a_raw = [np.hstack([b.columns[i] for b in blocks]) for blocks, i in zip(raw, rows)]
            rows = [slice(None)] * len(records)
        self.rows = rows
        self.target = self.sign * target  # fitted in the actuator's own direction (bounded weights ≥ 0)
        self.row_local = next((n for n in model.transforms if EFFECTS[n].row_local), None)
        #: record index -> its columns through every transform but the one ``design(exact=…)`` searches
        self.cache: dict = {}

    def design(self, theta: dict, exact: str | None = None) -> np.ndarray:
        """The training rows' columns for ``theta``. A row-local transform (a delay) is applied
        at those rows only, after the others (which commute with it); ``exact`` names one being
        searched, whose input columns are then cached across the search (``cache``)."""
        parts = []
        for k, r in enumerate(self.records):
            local = exact or (self.row_local if self.row_local in theta else None)
            if local is None:
                parts.append(self.model._transform_rows(self.a_raw[k], r.sample_rate_hz, theta, self.rows[k]))
            elif exact is not None:
                if k not in self.cache:
                    self.cache[k] = self.model._transform(self.a_raw[k], r.sample_rate_hz, theta, skip=exact)
                parts.append(EFFECTS[local].apply_rows(self.cache[k], r.sample_rate_hz, theta[local], self.rows[k]))
            else:
                parts.append(self._delayed_rows(k, r, theta, local))
        return np.vstack(parts)

    def _delayed_rows(self, k: int, r: Record, theta: dict, local: str) -> np.ndarray:
        """Record ``k``'s training rows through the row-local transform ``local``: the others'
        output at the rows the delay reads, then the delay's weighted sum."""
        taps = EFFECTS[local].taps(r.sample_rate_hz, theta[local], self.rows[k], r.n_samples)
        read = np.unique(np.concatenate([tap_rows for _, tap_rows in taps]))
        base = self.model._transform_rows(self.a_raw[k], r.sample_rate_hz, theta, read, skip=local)
        return sum_of_taps([(w, np.searchsorted(read, tap_rows)) for w, tap_rows in taps], base)

    def solve_design(self, a: np.ndarray, extra: Block | None = None):
        """The bounded weights (an LsqSolution: coef, rms µm) on the design ``a`` (and ``extra``)."""
        s = self.splits
        blocks = [Block(nm, (a[:, s[j] : s[j + 1]],), self.lower[j], self.upper[j]) for j, nm in enumerate(self.names)]
        return solve_blocks(blocks + ([extra] if extra is not None else []), self.target)

    def solve(self, theta: dict, exact: str | None = None):
        """Weights for ``theta`` (see ``design``)."""
        return self.solve_design(self.design(theta, exact))


def remembered(cost: Callable[[dict], float]) -> Callable[[dict], float]:
    """``cost(theta)`` computed once per parameter set (an exact cost is a whole solve; a search's
    refinement re-asks for the grid point it starts from)."""
    seen: dict[tuple, float] = {}

    def once(theta: dict) -> float:
        key = tuple(sorted(theta.items()))
        if key not in seen:
            seen[key] = cost(theta)
        return seen[key]

    return once


OUTER_ITERATIONS = 2
#: the joint polish of the free transforms: first step (fraction of each parameter) and evaluations
JOINT_STEP, JOINT_EVALUATIONS = 0.1, 80


class TransformSearch:
    """The searches for the transforms' parameters, mixed into CompositeModel (whose ``transforms``,
    ``_transform``, ``scales``, ``_fs`` and ``_config`` they read); each returns (theta, solution) or
    one transform's parameters."""

    def _refine_locally(self, problem: FitProblem, free: list[str], start: dict):
        """Each free transform refined once from ``start`` (parameters another model found: the
        effect's local search, not its grid), the exact cost re-solving every weight; (theta, solution)."""
        theta = {name: dict(start[name]) for name in self.transforms}
        for name in free:
            problem.cache.clear()
            exact = name if EFFECTS[name].row_local else None
            theta[name] = self._local_refine(
                name,
                theta[name],
                lambda th, name=name, exact=exact: problem.solve({**theta, name: th}, exact=exact).rms,
            )
        return theta, problem.solve(theta)

    def _search_transforms(self, problem: FitProblem, free: list[str], fixed_theta: dict):
        """The free transforms searched from identity; (theta, solution).

        A delay and a resonance both lag the output: searched one after the other, the first takes
        the whole lag and the search can stay in that basin. Each free transform is searched first
        once and the lower training cost kept (the first order on a tie), so the answer does not
        hang on which basin a rounding error tips the grid into."""
        orders = [free[i:] + free[:i] for i in range(len(free))] or [[]]
        theta, sol = self._descend(problem, orders[0], fixed_theta)
        for order in orders[1:]:
            other_theta, other = self._descend(problem, order, fixed_theta)
            if other.rms < sol.rms:
                theta, sol = other_theta, other
        if len(free) > 1:
            theta, sol = self._joint_polish(free, theta, sol, problem.solve)
        return theta, sol

    def _descend(self, problem: FitProblem, order: list[str], fixed_theta: dict):
        """Alternate searches of the free transforms in ``order`` (each with the others held),
        from every transform at identity; (theta, solution)."""
        theta = {name: dict(fixed_theta.get(name) or self._identity_theta(name)) for name in self.transforms}
        sol = problem.solve(theta)
        for it in range(OUTER_ITERATIONS if order else 0):
            for name in order:
                theta[name] = self._search_one(problem, name, theta, sol, last=it == OUTER_ITERATIONS - 1)
            sol = problem.solve(theta)
        return theta, sol

    def _search_one(self, problem: FitProblem, name: str, theta: dict, sol, last: bool) -> dict:
        """The parameters of transform ``name`` with the others held at ``theta``: a row-local one
        (a delay) on a grid of the exact cost; the harmonics with every weight refitted (already
        fine); else a grid on the current prediction (``sol``), refined with the exact cost in the
        ``last`` round."""
        if EFFECTS[name].row_local:
            problem.cache.clear()
            return self._grid_refine(name, lambda th: problem.solve({**theta, name: th}, exact=name).rms)

        def exact_cost(th: dict) -> float:
            return problem.solve({**theta, name: th}).rms

        best = self._harmonic_search(name, problem.a_raw, problem.records, theta)
        if best is None:
            z = [
                self._transform(problem.a_raw[k] @ sol.coef, r.sample_rate_hz, theta, skip=name)
                for k, r in enumerate(problem.records)
            ]
            best = self._search(name, z, problem.records, problem.rows, problem.target)
            return EFFECTS[name].refine(best, exact_cost) if last else best
        if last:  # the harmonics ignore bounds and transients: a last exact polish
            return EFFECTS[name].refine(best, exact_cost, fine=True)
        return best

    def _identity_theta(self, name: str) -> dict:
        return dict(EFFECTS[name].identity)

    def _harmonic_search(self, name, a_raw, records, theta) -> dict | None:
        """A transform's parameters from the periodic blocks' harmonics (None if it has no such
        search or the data has too few periodic blocks)."""
        eff = EFFECTS[name]
        if not hasattr(eff, "harmonic_search"):
            return None
        columns = [self._transform(a, r.sample_rate_hz, theta, skip=name) for a, r in zip(a_raw, records)]
        return eff.harmonic_search(
            harmonic_data(records, columns), records[0].sample_rate_hz, 1.0 / self.scales["min_period_s"]
        )

    def _search(self, name, z, records, rows, target) -> dict:
        """Best parameters of one transform for the current prediction ``z`` (gain and offset free)."""
        eff = EFFECTS[name]

        def cost(th):
            col = np.concatenate(
                [eff.apply(zk[:, None], r.sample_rate_hz, th)[rows[k], 0] for k, (zk, r) in enumerate(zip(z, records))]
            )
            a = np.column_stack([col, np.ones_like(col)])
            coef, *_ = np.linalg.lstsq(a, target, rcond=None)
            return float(np.sum((target - a @ coef) ** 2))

        return self._grid_refine(name, cost, records[0].sample_rate_hz)

    def _joint_polish(self, free: list[str], theta: dict, sol, solve):
        """All free transforms' parameters refined together (Nelder–Mead on the exact training cost,
        each parameter in units of its own size): one transform searched while the others are held
        moves slowly along a valley where they trade off (a delay against a mode's damping)."""
        keys = [(name, key) for name in free for key in theta[name]]
        floor = {"delay_s": 1.0 / self._fs}
        scale = np.array([max(abs(theta[n][k]), floor.get(k, 1e-12)) for n, k in keys])

        def unpack(x):
            out = {n: dict(theta[n]) for n in theta}
            for (n, k), v in zip(keys, x * scale):
                out[n][k] = float(v)
            return {n: EFFECTS[n].clamp(out[n], self._fs) if n in free else out[n] for n in out}

        x0 = np.ones(len(keys))
        simplex = np.vstack([x0] + [x0 + JOINT_STEP * np.eye(len(keys))[i] for i in range(len(keys))])
        res = minimize(
            lambda x: solve(unpack(x)).rms,
            x0,
            method="Nelder-Mead",
            options={"initial_simplex": simplex, "xatol": 1e-4, "fatol": 1e-6 * sol.rms, "maxfev": JOINT_EVALUATIONS},
        )
        if res.fun < sol.rms:
            best = unpack(res.x)
            return best, solve(best)
        return theta, sol

    def _local_refine(self, name: str, start: dict, cost) -> dict:
        """``name``'s parameters refined from ``start`` by its local search; a one-parameter grid
        brackets it by one grid step either side (a delay held at 0.9 µs can still reach 30 µs)."""
        eff = EFFECTS[name]
        if len(start) != 1:
            return eff.refine(start, cost)
        (key,) = start
        grid = eff.grid(self._fs, self.scales["min_period_s"], 1.0 / self.scales["min_period_s"])
        values = np.unique([float(g[key]) for g in grid])
        step = float(np.max(np.diff(values))) if values.size > 1 else abs(float(start[key]))
        return eff.refine(
            start, cost, bracket=({key: max(float(values[0]), start[key] - step)}, {key: start[key] + step})
        )

    def _grid_refine(self, name, cost, sample_rate_hz=None) -> dict:
        eff = EFFECTS[name]
        cost = remembered(cost)  # the refinement starts from the grid's best, whose cost is known
        fs = sample_rate_hz or self._fs
        grid = eff.grid(fs, self.scales["min_period_s"], 1.0 / self.scales["min_period_s"])
        costs = [cost(th) for th in grid]
        best = int(np.argmin(costs))
        return eff.refine(grid[best], cost, bracket=(grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]))
