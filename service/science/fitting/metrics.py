"""Fit metrics between a measured and a predicted displacement record, and the one RMS helper."""

from __future__ import annotations

import numpy as np


def rms(values) -> float:
    """Root mean square of ``values`` (in their unit); 0.0 when there are none."""
    v = np.asarray(values, dtype=float)
    return float(np.sqrt(np.mean(np.square(v)))) if v.size else 0.0


def fit_metrics(x_measured_um, x_predicted_um) -> dict:
    """``rms_um``, ``max_abs_um`` and the MATLAB-style ``fit_percent`` = 100·(1 − ‖e‖/‖x − mean x‖)."""
    x = np.asarray(x_measured_um, dtype=float)
    p = np.asarray(x_predicted_um, dtype=float)
    if x.shape != p.shape:
        raise ValueError(f"measured has shape {x.shape} but predicted has {p.shape}")
    e = x - p
    spread = float(np.linalg.norm(x - x.mean()))
    return {
        "rms_um": rms(e),
        "max_abs_um": float(np.max(np.abs(e))),
        "fit_percent": float(100.0 * (1.0 - np.linalg.norm(e) / spread)) if spread > 0 else float("nan"),
    }
