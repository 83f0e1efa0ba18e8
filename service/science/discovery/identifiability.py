"""What the data must contain before an effect can be tested at all.

An effect the experiment cannot tell apart from the hysteresis base, or from another effect, is
*not testable* on that data: it is reported with the reason and a ready-to-POST ``/api/sweeps``
body that would test it, and it is never claimed. Each effect carries its own rule (``rule`` in
words, ``untestable(records)``, ``sweep``: service.science.effects.base); the helpers the built-ins
share are in service.science.effects.rules. Pure numpy: no store, no HTTP.
"""

from __future__ import annotations

import numpy as np

from service.science.data.plans import PlanBase
from service.science.effects import EFFECTS
from service.science.effects.rules import (  # noqa: F401  (re-exported: the rules' figures and helpers)
    INDEPENDENT_SHARE,
    MIN_RATE_RATIO,
    MIN_TEMPERATURE_SPAN_K,
    RATE_SWEEP,
    drive_rates_hz,
    other_axis_independence,
)


def experiment_body(records, axes: list[str], **body) -> dict:
    """A ready-to-POST /api/sweeps body on ``axes``; a sine or step sweep spans the data's own drive
    range (``v_min``/``v_max``, V, rounded out to 0.1 V; a step's ``levels_v``, given on a default plan's
    0–120 V, moved onto it in proportion), so that an experiment asked for data of another stage or
    range is that range — and a bench that cannot drive it refuses it, naming the field."""
    out = {"axes": axes, **body}
    drives = [np.asarray(r.u_v, dtype=float) for r in records if getattr(r, "u_v", None) is not None and r.u_v.size]
    if body.get("waveform") not in ("sine", "step") or not drives:
        return out
    lo, hi = min(float(u.min()) for u in drives), max(float(u.max()) for u in drives)
    if hi <= lo:
        return out
    v_min, v_max = float(np.floor(lo * 10.0) / 10.0), float(np.ceil(hi * 10.0) / 10.0)
    out.update(v_min=v_min, v_max=v_max)
    if body.get("levels_v"):  # an effect's step levels are on a default plan's range: moved onto the data's
        nominal = PlanBase()
        share = (np.asarray(body["levels_v"], dtype=float) - nominal.v_min) / (nominal.v_max - nominal.v_min)
        out["levels_v"] = [float(np.clip(round(v_min + x * (v_max - v_min), 1), v_min, v_max)) for x in share]
    return out


def _axes(records) -> list[str]:
    return sorted({r.axis for r in records if r.axis}) or ["y"]


def _other(axis: str) -> str:
    return {"y": "z", "z": "y"}.get(axis, "z")


def not_testable(effect: str, records) -> dict | None:
    """None when ``records`` can test ``effect``; else ``{"effect", "reason", "experiment"}`` with
    the ``/api/sweeps`` body (the effect's ``sweep``) that would make it testable."""
    eff = EFFECTS[effect]
    reason = eff.untestable(records)
    if reason is None:
        return None
    axes = _axes(records)
    if eff.sweep_both_axes:
        axes = sorted(set(axes) | {_other(axes[0])})
    return {"effect": effect, "reason": reason, "experiment": experiment_body(records, axes, **eff.sweep)}
