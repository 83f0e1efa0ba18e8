"""Temperature: the stack's gain changes with its temperature (d33 and the switched strain of a
PZT stack rise a few 0.1 %/K). Columns: the temperature deviation from the data set's mean times
the normalised drive and the normalised hysteretic state, ΔT·u/u_max and ΔT·S/u_max (µm/K); zero
where the record carries no temperature (a feedforward inverse, a record without a thermometer).
Testable only on records whose ``temp_c`` varies (service/science/discovery/identifiability.py)."""

from __future__ import annotations

import numpy as np

from service.science.data.units import plain
from service.science.effects.base import Effect, RecordContext
from service.science.effects.rules import temperature_span
from service.science.fitting.lsq import Block


class Temperature(Effect):
    name = "temperature"
    signature = "the loop's size follows the measured temperature (temp_c): the stroke grows as the stack warms"

    def blocks(self, ctx: RecordContext) -> list[Block]:
        if ctx.temp_dev_k is None:
            return [Block.make("temperature_um_per_k", np.zeros((ctx.n, 2)))]
        u = ctx.u_v / ctx.u_scale_v
        s = ctx.p[:, 1:].sum(axis=1) / ctx.u_scale_v if ctx.p.shape[1] > 1 else u
        return [Block.make("temperature_um_per_k", np.column_stack([ctx.temp_dev_k * u, ctx.temp_dev_k * s]))]

    def describe(self, theta, values):
        p = self.parameters(theta, values, {}, 1.0)
        return "" if not p else f"gain change {plain(p['gain_change_nm_per_k'])} nm/K at full drive"

    def parameters(self, theta, values, scales, sign):
        """``gain_change_nm_per_k``: the output's change per kelvin at full drive (nm/K), as the words print it."""
        w = values.get("temperature_um_per_k")
        return {} if w is None else {"gain_change_nm_per_k": float(np.sum(w)) * 1e3}

    units = {"temperature_um_per_k": "µm/K", "gain_change_nm_per_k": "nm/K"}
    rule = "a temp_c column that varies by at least 0.5 K"
    sweep = {"waveform": "sine", "frequencies_hz": [1.0], "cycles": 60}
    emulator_bench = "temperature"

    def untestable(self, records):
        return temperature_span(records)
