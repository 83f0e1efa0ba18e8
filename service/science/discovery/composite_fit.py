"""The composite model's fit problem (service.science.discovery.composite): the training rows'
design for a set of transform parameters, and the bounded least-squares solve over it.

The raw columns (play operators, offset, effect columns) are built once per fit; a transform
(filter, delay) is applied to them for each ``theta`` tried. Pure numpy: no store, no HTTP.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from service.science.data.record import Record
from service.science.data.signals import sensitivity_sign
from service.science.effects import EFFECTS
from service.science.effects.base import sum_of_taps
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
