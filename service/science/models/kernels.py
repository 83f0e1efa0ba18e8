"""Compiled per-sample recursions: play operators (eq. 1), the rate-dependent play operator
(eq. 13), the paper's four-segment rule (eq. 3), and one generalised PI step.

Every operator in the package goes through :func:`play`, so eq. 1 and eq. 13 share one
definition. The scalar/in-place kernels are meant to be called from other numba code
(controllers run them sample by sample).
"""

from __future__ import annotations

import numpy as np

from drivers.jit import njit


@njit(cache=True, inline="always")
def play(h_l: float, h_r: float, r: float, y_prev: float) -> float:
    """One play-operator update: ``max(h_l − r, min(h_r + r, y_prev))`` (eq. 1 with h_l = h_r = u)."""
    return max(h_l - r, min(h_r + r, y_prev))


@njit(cache=True, nogil=True)
def play_update(u: float, thresholds: np.ndarray, state: np.ndarray) -> None:
    """Advance every classical play operator one sample; ``state`` (V) is updated in place."""
    for i in range(thresholds.size):
        state[i] = play(u, u, thresholds[i], state[i])


@njit(cache=True, nogil=True)
def _envelope_play_operators(h_l, h_r, thresholds, y0, out):
    state = y0.copy()
    for k in range(h_l.size):
        for i in range(thresholds.size):
            state[i] = play(h_l[k], h_r[k], thresholds[i], state[i])
            out[k, i] = state[i]


def _initial_state(y0, n: int) -> np.ndarray:
    if y0 is None:
        return np.zeros(n)
    y0 = np.broadcast_to(np.asarray(y0, dtype=float), (n,)).copy()
    return y0


def envelope_play_operators(h_l, h_r, thresholds, y0=None) -> np.ndarray:
    """Outputs (n_samples, n_thresholds) of play operators between envelopes ``h_l``/``h_r``."""
    h_l = np.ascontiguousarray(h_l, dtype=float)
    h_r = np.ascontiguousarray(h_r, dtype=float)
    r = np.ascontiguousarray(np.atleast_1d(thresholds), dtype=float)
    if h_l.shape != h_r.shape or h_l.ndim != 1:
        raise ValueError(f"envelopes must be 1-D of equal length, got {h_l.shape} and {h_r.shape}")
    out = np.empty((h_l.size, r.size))
    _envelope_play_operators(h_l, h_r, r, _initial_state(y0, r.size), out)
    return out


def play_operators(u, thresholds, y0=None) -> np.ndarray:
    """Eq. 1 for many thresholds at once: outputs (n_samples, n_thresholds) in V."""
    u = np.ascontiguousarray(u, dtype=float)
    return envelope_play_operators(u, u, thresholds, y0)


def grpi_envelopes(u, du, a1: float, a2: float, b1: float, b2: float):
    """GRPI envelopes (eq. 13): ``h_l = a1 u + a2|u̇|``, ``h_r = b1 u + b2|u̇|`` (V)."""
    speed = np.abs(du)
    return a1 * u + a2 * speed, b1 * u + b2 * speed


@njit(cache=True, nogil=True)
def segment_of(du: float, ddu: float) -> int:
    """Segment 0..3 of eq. 3 (paper's s = 1..4): the first matching row in the paper's order.

    s=1: u̇≥0, ü≥0;  s=2: u̇≥0, ü≤0;  s=3: u̇≤0, ü≤0;  s=4: u̇≤0, ü≥0.
    """
    if du >= 0.0:
        return 0 if ddu >= 0.0 else 1
    return 2 if ddu <= 0.0 else 3


@njit(cache=True, nogil=True)
def segment_index(du: np.ndarray, ddu: np.ndarray) -> np.ndarray:
    """:func:`segment_of` for every sample."""
    out = np.empty(du.size, dtype=np.int64)
    for k in range(du.size):
        out[k] = segment_of(du[k], ddu[k])
    return out


@njit(cache=True, nogil=True)
def dynamic_weight_shift(du: float, ddu: float, alpha: np.ndarray, beta: np.ndarray) -> float:
    """φ of eq. 3 in µm/V: ``α_s u̇ + β_s ü`` with s from the signs of (u̇, ü)."""
    s = segment_of(du, ddu)
    return alpha[s] * du + beta[s] * ddu


@njit(cache=True, nogil=True)
def gpi_step(u, a1, c_l, b1, c_r, thresholds, gains, offset, state, commit):
    """Generalised PI output (µm) at one sample with envelopes ``a1 u + c_l`` / ``b1 u + c_r``.

    Covers eq. 2 (a1=b1=1, c=0, gains=ω), eq. 4 (gains=ω+φ) and eq. 13 (c = a2|u̇|, b2|u̇|).
    ``state`` holds the operator outputs of the previous sample; it is overwritten
    only when ``commit`` is true.
    """
    h_l = a1 * u + c_l
    h_r = b1 * u + c_r
    x = offset
    for i in range(thresholds.size):
        y = play(h_l, h_r, thresholds[i], state[i])
        x += gains[i] * y
        if commit:
            state[i] = y
    return x
