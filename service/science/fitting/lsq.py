"""Bounded linear least squares over named design-matrix blocks, and variable projection.

A model (or an effect) contributes column blocks with per-column bounds; blocks with
the same name from several records are stacked row-wise and all blocks are solved
jointly, so later effect regressors (creep, delay, drift, ...) simply append blocks.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import solve_triangular
from scipy.linalg.lapack import dgeqrf
from scipy.optimize import least_squares, lsq_linear

from service.science.interrupt import checkpoint


@dataclass(frozen=True)
class Block:
    """Columns (n_samples, p) of one parameter group with per-column bounds.

    The rows may be held as several ``parts`` (one per record, see :func:`stack_blocks`);
    :attr:`columns` joins them on demand, the solver reads them in place.
    """

    name: str
    parts: tuple
    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def make(cls, name: str, columns, lower=-np.inf, upper=np.inf) -> Block:
        cols = np.asarray(columns, dtype=float)
        if cols.ndim == 1:
            cols = cols[:, None]
        p = cols.shape[1]
        lo = np.broadcast_to(np.asarray(lower, dtype=float), (p,)).copy()
        hi = np.broadcast_to(np.asarray(upper, dtype=float), (p,)).copy()
        if np.any(lo > hi):
            raise ValueError(f"block {name!r}: a lower bound exceeds its upper bound")
        return cls(name, (cols,), lo, hi)

    @property
    def columns(self) -> np.ndarray:
        return self.parts[0] if len(self.parts) == 1 else np.vstack(self.parts)

    @property
    def width(self) -> int:
        return self.parts[0].shape[1]

    @property
    def part_rows(self) -> tuple[int, ...]:
        return tuple(part.shape[0] for part in self.parts)


def stack_blocks(per_record: Sequence[Sequence[Block]]) -> list[Block]:
    """Stack same-named blocks of several records row-wise (records fitted jointly), without copying."""
    first = per_record[0]
    names = [b.name for b in first]
    for blocks in per_record[1:]:
        if [b.name for b in blocks] != names:
            raise ValueError("every record must contribute the same blocks in the same order")
    return [
        Block(b.name, tuple(part for blocks in per_record for part in blocks[j].parts), b.lower, b.upper)
        for j, b in enumerate(first)
    ]


def design_matrix(blocks: Sequence[Block]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, lower, upper) with the blocks side by side."""
    return (
        np.hstack([b.columns for b in blocks]),
        np.concatenate([b.lower for b in blocks]),
        np.concatenate([b.upper for b in blocks]),
    )


@dataclass
class LsqSolution:
    """Coefficients per block name, the residual (target − fit) and its RMS (weighted:
    √(Σ(w r)²/Σw²), i.e. over the weighted rows)."""

    values: dict[str, np.ndarray]
    coef: np.ndarray
    residual: np.ndarray
    rms: float
    active: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))


#: Rows per chunk of [A | b]: a chunk stays in cache.
CHUNK_ROWS = 16384
#: The normal equations are used while the unit-column triangle's condition number stays
#: below this (≤ ~8 digits lost, against 16); above it the chunked QR takes over.
GRAM_MAX_COND = 1e4
#: Below this (2.2e-308) a float is subnormal: each product with one costs ~25x a normal one
#: (measured: the Gram of an 11 200 x 87 design, 40 % of its entries the tail of a filter that
#: came to rest, 72 ms against 3 ms). The chunks flush them to 0; nothing a fit sees is that small.
SMALLEST_NORMAL = float(np.finfo(float).tiny)
#: The damping of the solve, per unit column: a combination of unit-norm columns whose norm is below
#: this is not determined by any record (a record's noise alone is ~1e-5 of its span), and an exact
#: solve puts weights along it that cancel on the training rows only. A composite model with the gauge's
#: bow and the fine hysteron grid (305 columns, singular values down to 3e-9) was stored with weights
#: of 3.6e7 µm that cancelled there and predicted 1.6e16 µm from the rest before its first cycle.
#: Damped (Tikhonov, λ = DAMPING²), such directions keep weights near 0; a determined one (singular
#: value s) is scaled by s²/(s² + λ), 1 − 1e-6 at the well-conditioned limit (s ≥ 1e-4).
DAMPING = 1e-7


def _aligned_parts(blocks: Sequence[Block], n: int) -> list[list[np.ndarray]]:
    """Per row-part, the blocks' columns; blocks split differently are joined into one part."""
    splits = {blk.part_rows for blk in blocks}
    for blk in blocks:
        if sum(blk.part_rows) != n:
            raise ValueError(f"block {blk.name!r} has {sum(blk.part_rows)} rows but the target has {n} samples")
    if len(splits) == 1:
        return [list(cols) for cols in zip(*(blk.parts for blk in blocks))]
    return [[blk.columns for blk in blocks]]


def _chunks(parts: list[list[np.ndarray]], b: np.ndarray, w):
    """Row chunks of the weighted [A | b] as Fortran arrays, read from the parts in place, with
    subnormal entries flushed to 0 (see ``SMALLEST_NORMAL``)."""
    p = sum(cols.shape[1] for cols in parts[0])
    offset = 0
    for cols in parts:
        n_part = cols[0].shape[0]
        for start in range(0, n_part, CHUNK_ROWS):
            rows = slice(start, min(start + CHUNK_ROWS, n_part))
            glob = slice(offset + rows.start, offset + rows.stop)
            chunk = np.empty((rows.stop - rows.start, p + 1), order="F")
            col = 0
            for c in cols:
                chunk[:, col : col + c.shape[1]] = c[rows]
                col += c.shape[1]
            chunk[:, p] = b[glob]
            if w is not None:
                chunk *= w[glob, None]
            chunk[np.abs(chunk) < SMALLEST_NORMAL] = 0.0
            yield chunk
        offset += n_part


def _qr_r(m: np.ndarray) -> np.ndarray:
    """Upper-triangular R of ``m`` (Householder, LAPACK geqrf; Q never formed)."""
    packed, _, _, info = dgeqrf(m, overwrite_a=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"QR factorisation failed (LAPACK info {info})")
    return np.triu(packed[: min(m.shape), :])


def _triangle(parts, b, w, p):
    """(R, rhs, scale, live): ‖Ax − b‖² = ‖R (scale·x)[live] − rhs‖² + const, R for unit columns.

    First the normal equations (eq. 8's Σ p pᵀ, Cholesky); if they are too ill-conditioned,
    the QR of [A | b] by chunks (TSQR).
    """
    gram = np.zeros((p + 1, p + 1))
    for chunk in _chunks(parts, b, w):
        gram += chunk.T @ chunk
    scale = np.sqrt(np.diag(gram)[:p])  # column norms of A
    live = scale > 0.0
    scale[~live] = 1.0
    s = scale[live]
    try:
        r = np.linalg.cholesky(gram[:p, :p][np.ix_(live, live)] / np.outer(s, s)).T
        if np.linalg.cond(r) <= GRAM_MAX_COND:
            return r, solve_triangular(r, gram[:p, p][live] / s, trans="T"), scale, live
    except np.linalg.LinAlgError:
        pass
    triangles = [_qr_r(chunk) for chunk in _chunks(parts, b, w)]
    r_aug = triangles[0] if len(triangles) == 1 else _qr_r(np.asfortranarray(np.vstack(triangles)))
    return r_aug[:p, :p][:, live] / s, r_aug[:p, p], scale, live


def solve_blocks(blocks: Sequence[Block], target, row_weights=None) -> LsqSolution:
    """Minimise ‖W(target − Σ_b A_b c_b)‖² subject to each block's bounds, exactly.

    [A | b] is reduced to a p×p triangle for unit-norm columns (normal equations, or QR
    when ill-conditioned; read in place, record by record) and BVLS solves the small
    problem, damped by DAMPING per unit column (directions no record determines keep weights
    near 0). All-zero columns get the in-bounds value nearest 0. ``row_weights``
    (optional, n_samples) multiplies each residual sample; the residual is unweighted. A
    checkpoint (service.science.interrupt): a cancelled owner's fit stops here.
    """
    checkpoint()
    b = np.asarray(target, dtype=float)
    parts = _aligned_parts(blocks, b.size)
    lower = np.concatenate([blk.lower for blk in blocks])
    upper = np.concatenate([blk.upper for blk in blocks])
    p = lower.size
    w = None if row_weights is None else np.asarray(row_weights, dtype=float)
    coef = np.clip(np.zeros(p), lower, upper)
    r, rhs, scale, live = _triangle(parts, b, w, p)
    if np.any(live):
        s = scale[live]
        lo, hi = lower[live] * s, upper[live] * s
        r = np.vstack([r, DAMPING * np.eye(r.shape[1])])
        rhs = np.concatenate([rhs, np.zeros(r.shape[1])])
        if np.all(np.isinf(lo)) and np.all(np.isinf(hi)):
            z = np.linalg.lstsq(r, rhs, rcond=None)[0]
        else:
            z = lsq_linear(r, rhs, bounds=(lo, hi), method="bvls", tol=1e-14, max_iter=100 * p).x
        coef[live] = np.clip(z / s, lower[live], upper[live])  # BVLS may overshoot a bound by 1 ulp
    splits = np.cumsum([0] + [blk.width for blk in blocks])
    values = {blk.name: coef[splits[j] : splits[j + 1]] for j, blk in enumerate(blocks)}
    fitted = [sum(c @ coef[splits[j] : splits[j + 1]] for j, c in enumerate(cols)) for cols in parts]
    residual = b - np.concatenate(fitted)
    active = (coef <= lower) | (coef >= upper)
    rms = np.sqrt(np.mean(residual**2)) if w is None else np.sqrt(np.sum((w * residual) ** 2) / np.sum(w**2))
    return LsqSolution(values, coef, residual, float(rms), active)


@dataclass
class SeparableSolution:
    """Nonlinear parameters ``theta``, the inner linear solution, and the optimiser's report."""

    theta: np.ndarray
    linear: LsqSolution
    nfev: int
    njev: int
    message: str


def separable_least_squares(
    make_blocks: Callable[[np.ndarray], Sequence[Block]],
    target,
    theta0,
    theta_scale=None,
    bounds=(-np.inf, np.inf),
    row_weights=None,
) -> SeparableSolution:
    """Variable projection: minimise over ``theta`` the (row-weighted) residual left by the
    bounded linear solve of ``make_blocks(theta)`` (scipy ``least_squares``, finite-difference
    Jacobian).
    """
    b = np.asarray(target, dtype=float)
    theta0 = np.asarray(theta0, dtype=float)
    scale = np.ones_like(theta0) if theta_scale is None else np.asarray(theta_scale, dtype=float)
    w = 1.0 if row_weights is None else np.asarray(row_weights, dtype=float)

    def residual(z):
        return w * solve_blocks(make_blocks(z * scale), b, row_weights).residual

    lo, hi = (np.broadcast_to(np.asarray(v, dtype=float), theta0.shape) / scale for v in bounds)
    res = least_squares(
        residual,
        theta0 / scale,
        bounds=(lo, hi),
        method="trf",
        x_scale=1.0,
        diff_step=1e-6,
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
        max_nfev=200,
    )
    theta = res.x * scale
    return SeparableSolution(
        theta, solve_blocks(make_blocks(theta), b, row_weights), int(res.nfev), int(res.njev or 0), str(res.message)
    )
