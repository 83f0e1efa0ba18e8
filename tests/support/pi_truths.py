"""Known-parameter PI models that the identification and inverse tests generate data from."""

from __future__ import annotations

import numpy as np

from service.science.models import GRPI, DynamicPI, StaticPI, equal_thresholds

FS = 20_000.0  # Hz
#: µm/V per operator at thresholds 0, 6, …, 54 V: the shape of the paper's Table 2, all > 0.
WEIGHTS = np.array([0.0135, 0.0279, 0.001, 0.004, 0.0077, 0.002, 0.001, 0.0005, 0.0003, 0.0001])


def static_truth() -> StaticPI:
    m = StaticPI(thresholds_v=equal_thresholds(120.0, 10))
    m.weights_um_per_v, m.offset_um = WEIGHTS.copy(), 0.7
    return m


def dynamic_truth() -> DynamicPI:
    m = DynamicPI(thresholds_v=equal_thresholds(120.0, 10))
    m.weights_um_per_v, m.offset_um = WEIGHTS.copy(), -0.4
    m.alpha_um_per_v2_s = np.array([3e-9, -2e-9, 4e-9, -1e-9])
    m.beta_um_per_v2_s2 = np.array([2e-12, 4e-12, -3e-12, 1e-12])
    return m


def grpi_truth() -> GRPI:
    m = GRPI(thresholds_v=equal_thresholds(120.0, 10))
    m.weights_um_per_v, m.offset_um = WEIGHTS.copy(), 0.2
    m.a1, m.a2_s, m.b1, m.b2_s = 1.04, 1.5e-4, 0.97, -1.0e-4
    return m
