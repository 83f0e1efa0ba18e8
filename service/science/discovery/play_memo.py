"""The play operators' outputs of recent drives, kept for the fits that follow (see PlayOutputsMemo)."""
from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

from service.science.models.kernels import play_operators


class PlayOutputsMemo:
    """The play operators' outputs of the last few drives: a diagnosis fits a dozen models on the
    same records with the same thresholds, and each fit would otherwise replay every operator over
    every sample. Keyed by the drive array's identity (a reference is held, so the id stays its
    own), the origin (V) and the thresholds (V); bounded to ``size`` entries (each n × p floats)."""

    def __init__(self, size: int = 6):
        self.size, self._entries, self._lock = size, OrderedDict(), threading.Lock()

    def outputs(self, u_v: np.ndarray, origin_v: float, thresholds_v: np.ndarray) -> np.ndarray:
        key = (id(u_v), u_v.shape, float(origin_v), np.asarray(thresholds_v, dtype=float).tobytes())
        with self._lock:
            hit = self._entries.get(key)
            if hit is not None and hit[0] is u_v:
                self._entries.move_to_end(key)
                return hit[1]
        p = play_operators(u_v - origin_v, thresholds_v)
        p.flags.writeable = False          # shared between fits: nobody may change it in place
        with self._lock:
            self._entries[key] = (u_v, p)
            while len(self._entries) > self.size:
                self._entries.popitem(last=False)
        return p


#: the one memo of the process (a diagnosis's fits share it; jobs in threads are served under its lock)
PLAY_OUTPUTS = PlayOutputsMemo()
