"""The fitted physical parameters of a composite model as numbers, units in the names: each
effect's ``Effect.parameters`` (resonance_hz and damping_ratio, delay_us, creep_nm_per_decade and
creep_pct_per_decade, drift_nm_per_s, coupling_ratio, …). Pure numpy: no store, no HTTP."""

from __future__ import annotations

import numpy as np

from service.science.discovery.composite import CompositeModel
from service.science.effects import EFFECTS


def stroke_um(model: CompositeModel) -> float:
    """The hysteresis base's rise on a ramp from rest to the full drive scale (µm):
    Σ wᵢ·max(u_scale − rᵢ, 0) over its play operators (weights wᵢ µm/V, thresholds rᵢ V)."""
    rise_v = np.maximum(model.scales["u_scale_v"] - np.asarray(model.thresholds_v), 0.0)
    return float(np.asarray(model.coef["weights_um_per_v"]) @ rise_v)


def physical_parameters(model: CompositeModel) -> dict[str, dict[str, float]]:
    """Per effect of a fitted ``model``, its physical parameters (empty for one without any). The
    effects see the model's scales plus ``stroke_um``, against which a creep is a share per decade."""
    if not model.is_fitted:
        raise RuntimeError("composite model is not fitted")
    scales = {**model.scales, "stroke_um": stroke_um(model)}
    return {e: EFFECTS[e].parameters(model.theta.get(e, {}), model.coef, scales, model.sign) for e in model.effects}


def parameter_units(effect: str, names) -> dict[str, str]:
    """The unit of each of ``effect``'s parameters ``names`` as its contract states it ("" if none): the
    one lookup a page, the discover result and the report print units from."""
    return {name: EFFECTS[effect].units.get(name, "") for name in names}
