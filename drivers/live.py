"""Live signals: a ring buffer of decimated (t, u, x) samples per axis that the bench fills while it
streams, so a user can watch any job (a sweep, a trajectory, a calibration) as it runs.

The bench pushes every block it streams; the monitor keeps about ``rate_hz`` samples per second
of them (a stride that carries over from block to block, so the kept samples are evenly spaced)
and the last ``capacity`` of those. Readers ask for the samples after a cursor (the count of
samples ever kept) and get the new cursor back, so polling costs only what is new.

Each call to ``begin`` starts a run: its time restarts at 0 s and its samples carry the run's
number, so a reader can tell one job's signals from the next. No service code is imported here.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping, Sequence

import numpy as np

DEFAULT_RATE_HZ = 1000.0
DEFAULT_CAPACITY = 30_000


class LiveMonitor:
    """Thread-safe ring buffer of the latest decimated samples: t_s, run, and u_v, x_um per axis."""

    def __init__(self, axes: Sequence[str], rate_hz: float = DEFAULT_RATE_HZ, capacity: int = DEFAULT_CAPACITY):
        if rate_hz <= 0 or capacity <= 0:
            raise ValueError("rate_hz and capacity must be positive")
        self.axes = tuple(axes)
        self.rate_hz = float(rate_hz)
        self.capacity = int(capacity)
        # columns: t_s, run, then u_v per axis, then x_um per axis
        self._buf = np.zeros((self.capacity, 2 + 2 * len(self.axes)))
        self._total = 0  # samples ever kept (the cursor)
        self._run = 0
        self._label = ""
        self._source_rate_hz = 0.0
        self._stride = 1
        self._phase = 0  # source samples to skip before the next kept one
        self._t_index = 0  # source samples seen in this run
        self._lock = threading.Lock()

    def begin(self, sample_rate_hz: float, label: str = "") -> int:
        """Start a run streamed at ``sample_rate_hz``; returns its number."""
        with self._lock:
            self._run += 1
            self._label = label
            self._source_rate_hz = float(sample_rate_hz)
            self._stride = max(1, int(round(sample_rate_hz / self.rate_hz)))
            self._phase = 0
            self._t_index = 0
            return self._run

    def push(self, u_v: Mapping[str, np.ndarray], x_um: Mapping[str, np.ndarray]) -> None:
        """Append one streamed block (axis → samples; a missing axis, or the end of a shorter one,
        reads as NaN)."""
        n = max((len(v) for v in list(u_v.values()) + list(x_um.values())), default=0)
        if self._run == 0 or n == 0:
            return
        self.push_columns(_columns(u_v, self.axes, n), _columns(x_um, self.axes, n))

    def push_columns(self, u_v: np.ndarray, x_um: np.ndarray) -> None:
        """``push`` for (n, axes) arrays in ``self.axes`` order: what a loop that holds its signals
        as columns pushes once per period, without building a mapping or a mask."""
        n = u_v.shape[0]
        if self._run == 0 or n == 0:
            return
        with self._lock:
            first, stride, t0 = self._phase, self._stride, self._t_index
            self._phase = (first - n) % stride
            self._t_index += n
            if first >= n:
                return
            kept = np.arange(first, n, stride)
            rows = np.empty((len(kept), self._buf.shape[1]))
            rows[:, 0] = (t0 + kept) / self._source_rate_hz
            rows[:, 1] = self._run
            axes = len(self.axes)
            rows[:, 2 : 2 + axes] = u_v[first::stride]
            rows[:, 2 + axes :] = x_um[first::stride]
            self._append(rows[-self.capacity :])

    def _append(self, rows: np.ndarray) -> None:
        """Write ``rows`` after the newest kept sample, wrapping around the ring (lock held)."""
        start = self._total % self.capacity
        head = min(len(rows), self.capacity - start)
        self._buf[start : start + head] = rows[:head]
        self._buf[: len(rows) - head] = rows[head:]
        self._total += len(rows)

    def since(self, cursor: int | None = None, max_points: int = 2000) -> dict:
        """The kept samples from ``cursor`` on (or the latest ``max_points`` if None), thinned by a
        stride to at most ``max_points``; ``cursor`` in the answer is where the next call starts."""
        max_points = max(1, int(max_points))
        with self._lock:
            first = max(0, self._total - self.capacity)
            start = (
                max(first, self._total - max_points) if cursor is None else min(max(int(cursor), first), self._total)
            )
            n = self._total - start
            stride = max(1, math.ceil(n / max_points))
            pos = (start + np.arange(0, n, stride)) % self.capacity
            rows = self._buf[pos].copy()
            out = {
                "cursor": self._total,
                "first": first,
                "run": self._run,
                "label": self._label,
                "rate_hz": self._source_rate_hz / self._stride if self._source_rate_hz else self.rate_hz,
                "stride": stride,
                "dropped": max(0, first - int(cursor)) if cursor is not None else 0,
            }
        out["t_s"] = rows[:, 0].tolist()
        out["runs"] = rows[:, 1].astype(int).tolist()
        for j, axis in enumerate(self.axes):
            out[f"u_{axis}_v"] = _finite(rows[:, 2 + j])
            out[f"x_{axis}_um"] = _finite(rows[:, 2 + len(self.axes) + j])
        return out


def _columns(signals: Mapping[str, np.ndarray], axes: Sequence[str], n: int) -> np.ndarray:
    """(n, axes) array of ``signals`` in ``axes`` order: NaN where an axis is missing or shorter."""
    out = np.full((n, len(axes)), np.nan)
    for j, axis in enumerate(axes):
        values = signals.get(axis)
        if values is not None:
            values = np.asarray(values, dtype=float)[:n]
            out[: len(values), j] = values
    return out


def _finite(column: np.ndarray) -> list:
    """JSON-safe: NaN (an axis not streamed, a sample not measured) becomes null."""
    return [None if not math.isfinite(v) else float(v) for v in column]
