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
    range (``v_min``/``v_max``, V, rounded out to 0.1 V), so that an experiment asked for data of
    another stage or range is that range, and a bench that cannot drive it refuses it, naming the
    field. A step's ``level_shares`` (0…1 of that range, the effects' contract) become its ``levels_v``
    (V, rounded to 0.1 V; on a default plan's range where the records hold no drive); a sine's
    ``rate_multiples`` (of the data's fastest drive rate) become its ``frequencies_hz``."""
    out = {"axes": axes, **body}
    shares = out.pop("level_shares", None)
    multiples = out.pop("rate_multiples", None)
    if multiples is not None:  # rates above the data's: multiples of its fastest (a rate sweep's, 100 Hz, without one)
        fastest = fastest_drive_hz(records) or max(RATE_SWEEP["frequencies_hz"])
        out["frequencies_hz"] = [round(float(m) * fastest, 3) for m in multiples]
    drives = [np.asarray(r.u_v, dtype=float) for r in records if getattr(r, "u_v", None) is not None and r.u_v.size]
    lo = min((float(u.min()) for u in drives), default=0.0)
    hi = max((float(u.max()) for u in drives), default=0.0)
    spans_data = body.get("waveform") in ("sine", "step") and hi > lo
    if spans_data:
        out.update(v_min=float(np.floor(lo * 10.0) / 10.0), v_max=float(np.ceil(hi * 10.0) / 10.0))
    if shares is not None:
        nominal = PlanBase()
        v_min, v_max = (out["v_min"], out["v_max"]) if spans_data else (nominal.v_min, nominal.v_max)
        out["levels_v"] = [float(np.clip(round(v_min + x * (v_max - v_min), 1), v_min, v_max)) for x in shares]
    return out


def fastest_drive_hz(records) -> float | None:
    """The fastest rate (Hz) at which ``records`` drive their own axis, None where no block has one."""
    rates = [
        s.block["frequency_hz"] for r in records for s in r.splits_of(own_axis_only=True) if s.block.get("frequency_hz")
    ]
    return max(rates, default=None)


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
