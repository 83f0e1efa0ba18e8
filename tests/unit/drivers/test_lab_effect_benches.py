"""The emulator variants of issue 38 §3's effects (fixtures/benches/line_disturbance.toml, gain_change.toml,
slew_limit.toml): each bench's physics, measured on what its gauge and amplifier monitor read, against
the base bench. The emulator implements the physics (a line on the gauge, a depolarising stack, an
amplifier's current limit into the stack's capacitance), never the fitted model family."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.emulated import load_config
from drivers.factory import open_bench
from service.science.data import signals
from service.science.effects import EFFECTS
from service.science.effects.slew_limit import amplifier_slew_v_per_s

FS = 20000.0


def biased_sine(f: float, cycles: float = 5, v_max: float = 120.0) -> np.ndarray:
    return signals.biased_sine(f, cycles, FS, 0.0, v_max).value


def _line_nm(x_um: np.ndarray, f_hz: float) -> float:
    """The amplitude (nm) of the line at ``f_hz`` in ``x_um`` (mean and slope taken out)."""
    t = np.arange(x_um.size) / FS
    a = np.column_stack([np.sin(2 * np.pi * f_hz * t), np.cos(2 * np.pi * f_hz * t), np.ones_like(t), t])
    coef = np.linalg.lstsq(a, x_um, rcond=None)[0]
    return float(np.hypot(coef[0], coef[1]) * 1e3)


def test_every_new_effect_names_its_emulator_bench_and_the_bench_loads():
    for name in ("line_disturbance", "gain_change", "slew_limit"):
        assert load_config(EFFECTS[name].emulator_bench)["name"] == name


def test_the_line_bench_puts_a_mains_line_on_the_gauge_at_rest():
    """12 nm at 50 Hz and 4 nm at 150 Hz at 0 V (±10 %); the base bench shows under 0.5 nm there."""
    rest = np.zeros(int(FS))
    hum = open_bench("line_disturbance", seed=1).run({"y": rest}, FS).x_um["y"]
    clean = open_bench("base", seed=1).run({"y": rest}, FS).x_um["y"]
    assert _line_nm(hum, 50.0) == pytest.approx(12.0, rel=0.1)
    assert _line_nm(hum, 150.0) == pytest.approx(4.0, rel=0.1)
    assert _line_nm(clean, 50.0) < 0.5


def test_the_gain_change_bench_depolarises_with_time():
    """Three identical 10 Hz blocks 4 s apart: the stroke falls 0.3 %/s at first (loss 0.3, τ = 100 s),
    so the third block's peak-to-peak is 2.3 % (±0.15 %) below the first's; the base bench's within 0.05 %."""
    block = biased_sine(10.0, cycles=40)
    u = np.concatenate([block, block, block])
    depol = load_config("gain_change")["axes"]["y"]["piezo"]["depolarisation"]

    def gain(t_s: float) -> float:  # the bench's law, at the middle of a block's settled half
        return 1.0 + depol["loss_fraction"] * np.expm1(-t_s / depol["time_constant_s"])

    for bench, fall in (("gain_change", 1.0 - gain(11.0) / gain(3.0)), ("base", 0.0)):
        x = open_bench(bench, seed=2).run({"y": u}, FS).x_um["y"]
        n = block.size
        first, third = (x[k * n : (k + 1) * n][n // 2 :] for k in (0, 2))  # each block's settled half
        ratio = np.ptp(third) / np.ptp(first)
        assert 1 - ratio == pytest.approx(fall, abs=0.0015 if fall else 0.0005), bench


def test_the_slew_bench_limits_the_stack_to_its_current_over_its_capacitance():
    """70 mA into stacks rated 1.8 µF: the bench accepts a 100 Hz 0–120 V sine (37.7 kV/s at its steepest,
    under I/C = 38.9 kV/s), but at large signal the stacks hold 1.75× their rated charge, so their voltage
    moves at most 22.2 kV/s: the 100 Hz block's stroke shrinks by 4.5 % (more than 3 %) and the 50 Hz block's
    (18.8 kV/s) does not change; no over-current fault latches."""
    amp = load_config("slew_limit")["axes"]["y"]["amplifier"]
    rated = amplifier_slew_v_per_s(amp["current_limit_a"], amp["load_capacitance_f"])
    large_signal = amplifier_slew_v_per_s(
        amp["current_limit_a"], amp["load_capacitance_f"] * amp["large_signal_capacitance_factor"]
    )
    assert rated == pytest.approx(38889, rel=1e-3) and large_signal == pytest.approx(22222, rel=1e-3)
    for f_hz, limited in ((100.0, True), (50.0, False)):
        u = biased_sine(f_hz)
        x = open_bench("slew_limit", seed=3).run({"y": u}, FS).x_um["y"]
        base = open_bench("base", seed=3).run({"y": u}, FS).x_um["y"]
        held_back = (np.ptp(base) - np.ptp(x)) / np.ptp(base)
        assert held_back > 0.03 if limited else abs(held_back) < 0.002, (f_hz, held_back)
