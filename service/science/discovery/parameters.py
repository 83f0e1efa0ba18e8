"""The fitted physical parameters of a composite model as numbers, units in the names: each
effect's ``Effect.parameters`` (resonance_hz and damping_ratio, delay_us, creep_nm_per_decade and
creep_pct_per_decade, drift_nm_per_s, coupling_ratio, …). Pure numpy: no store, no HTTP."""

from __future__ import annotations

import numpy as np

from service.science.data.signals import drive_derivatives
from service.science.discovery.composite import CompositeModel
from service.science.effects import EFFECTS

#: samples of each leg of the quasi-static ramp ``stroke_um`` reads the base on, and their rate (Hz)
STROKE_RAMP_SAMPLES = 2001
STROKE_RAMP_RATE_HZ = 1.0


def stroke_um(model: CompositeModel) -> float:
    """The rate-independent base's rise from the drive's origin to its full scale in the steady state
    (µm): read on a slow ramp origin → top → origin → top, the last rise (the loop's ascending branch,
    which the data draw again and again, not the virgin curve, which they draw once at most). The base
    is the play operators and every effect of it (capacity, and the flexible base's loop shape:
    asymmetry). The play operators' weights alone left out the hysterons' free-sign corrections: a
    Bouc–Wen stage whose loop rises 9.5 µm read 5.1 µm on one record and 20.5 µm on one file per block,
    and every share of it (creep's %/decade, a gain's %) with it."""
    top = model.scales["u_scale_v"]
    leg = np.linspace(0.0, top, STROKE_RAMP_SAMPLES)
    u = model.u_origin_v + np.concatenate([leg, leg[::-1][1:], leg[1:]])
    ctx = model.context(u, STROKE_RAMP_RATE_HZ, *drive_derivatives(u, STROKE_RAMP_RATE_HZ), None, None, None)
    bottom = 2 * (STROKE_RAMP_SAMPLES - 1)  # the origin, after the descent

    def rise(columns: np.ndarray, weights) -> float:
        return float((columns[-1] - columns[bottom]) @ np.asarray(weights))

    total = rise(ctx.p, model.coef["weights_um_per_v"])
    for name in model.effects:
        effect = EFFECTS[name]
        if effect.kind == "capacity" or effect.in_flexible_base:
            total += sum(rise(block.columns, model.coef[block.name]) for block in effect.blocks(ctx))
    return abs(total)


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
