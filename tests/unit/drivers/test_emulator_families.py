"""The emulator's hysteresis families (issue 17 §5): Preisach (the default), Bouc–Wen, Maxwell-slip.

Each family is selected per axis by ``[axes.<axis>.piezo.hysteresis] family``; the rest of the stack
acts on its switched strain alike. The static PI here (``service.reports.calibration``: the paper's
10 play operators at 0, 6, …, 54 V, NNLS weights) is the model family the service fits; none of
the emulator's families is it, and the PI fits Preisach best.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from drivers.emulated import kernels as K
from drivers.emulated import load_config
from drivers.factory import open_bench
from service.reports.calibration import PAPER, biased_sine, last_cycle, loop_width, sweep_pi_rms
from service.science.data import signals

FS = 20000.0
FAMILIES = ("preisach", "bouc_wen", "maxwell_slip")
CLEAN = {"preisach": "base", "bouc_wen": "bw_base", "maxwell_slip": "ms_base"}
PREFIX = {"preisach": "", "bouc_wen": "bw_", "maxwell_slip": "ms_"}
EFFECTS = (
    "creep",
    "dynamics",
    "delay",
    "cross_coupling",
    "asymmetry",
    "drift",
    "rate_dependence",
    "sensor_nonlinearity",
    "temperature",
)
NOISELESS = {
    "axes.*.gauge.noise.enabled": False,
    "axes.*.amplifier.noise.enabled": False,
    "daq.quantisation.enabled": False,
}
#: sha256 of x_um (Y then Z, little-endian float64) of the default bench, seed 0, one 1 Hz cycle of
#: 0–120 V on Y and 0–96 V on Z at 20 kHz, computed with the code before the families existed (77764d0)
DEFAULT_1HZ_SHA256 = "7fba494930f35d10c6271a1be70c942ed0a504751f62eee9c5f5fa691f999118"
#: the Z values the default bench had then (issue 18 refitted them; Y's are unchanged): with them the
#: emulator must still reproduce that record bit for bit (a relaxing fraction of 1 is exactly the old law)
DEFAULT_BEFORE_TABLE6_FIT = {
    "axes.z.piezo.reversible_um_per_v": 0.0383,
    "axes.z.piezo.hysteresis.switched_um": 6.40,
    "axes.z.piezo.rate_dependence.relaxation_s": 1.0e-4,
    "axes.z.piezo.rate_dependence.relaxing_fraction": 1.0,
    "axes.z.piezo.creep.rate_per_decade": 0.015,
    "axes.z.piezo.asymmetry.electrostrictive_um_per_v2": 1.28e-5,
    "axes.z.piezo.asymmetry.saturation_um": 6.4,
    "axes.z.flexure.dynamics.damping_ratio": 0.05,
    "axes.z.gauge.bandwidth.bandwidth_hz": 10000.0,
}


def _true_x(bench: str, f_hz: float, cycles: int, fs: float = FS, overrides: dict | None = None):
    """Noise-free drive of both axes with the paper's biased sine; (actuator V, true µm) per axis."""
    b = open_bench(bench, seed=0, overrides={**NOISELESS, **(overrides or {})})
    fs = b.parts.daq.configure(fs)
    u = signals.biased_sine(f_hz, cycles, fs, 0.0, 120.0).value
    b.parts.daq.write_read(np.column_stack([u / 20.0, u / 20.0]))
    d = b.parts.world.last_diag
    return d[:, [K.D_VP_Y, K.D_VP_Z]], d[:, [K.D_X_Y, K.D_X_Z]]


def _branches(u: np.ndarray, x: np.ndarray, grid: np.ndarray):
    """The last cycle's rising and falling branches interpolated on ``grid`` (V)."""
    top = int(np.argmax(u))
    rise = np.interp(grid, u[: top + 1], x[: top + 1])
    fall = np.interp(grid, u[top:][::-1], x[top:][::-1])
    return rise, fall


def test_default_bench_is_unchanged_bit_for_bit():
    t = np.arange(int(FS)) / FS
    u = 60.0 - 60.0 * np.cos(2 * np.pi * t)
    rec = open_bench("default", seed=0, overrides=DEFAULT_BEFORE_TABLE6_FIT).run({"y": u, "z": 0.8 * u}, FS)
    h = hashlib.sha256()
    for axis in ("y", "z"):
        h.update(np.ascontiguousarray(rec.x_um[axis], dtype="<f8").tobytes())
    assert h.hexdigest() == DEFAULT_1HZ_SHA256
    assert load_config("default")["axes"]["y"]["piezo"]["hysteresis"]["family"] == "preisach"


@pytest.mark.parametrize("family", FAMILIES)
def test_stroke_and_loop_width_match_the_paper_bench(family):
    """The default bench with the family switched in, each axis driven alone at 1 Hz, 5 cycles,
    last cycle. Measured (stroke µm Y/Z, width % of stroke Y/Z): preisach 6.39/9.30, 12.1/11.9;
    bouc_wen 6.29/9.08, 12.4/11.9; maxwell_slip 6.31/9.02, 12.9/12.2. On the clean benches:
    preisach 7.09/10.47, 11.2/11.2; bouc_wen 7.02/10.29, 12.0/11.9; maxwell_slip 7.03/10.24,
    12.3/12.2."""
    u = biased_sine(1.0)
    for axis in ("y", "z"):
        rec = open_bench("default", seed=1, overrides={"axes.*.piezo.hysteresis.family": family}).run({axis: u}, FS)
        uc, xc = last_cycle(rec.u_cmd_v[axis], rec.x_um[axis], 1.0)
        stroke = xc.max() - xc.min()
        assert stroke == pytest.approx(PAPER[axis]["stroke_um"], rel=0.05), axis
        assert 10.0 <= 100.0 * loop_width(uc, xc) / stroke <= 15.0, axis


@pytest.mark.parametrize("family", ["bouc_wen", "maxwell_slip"])
def test_family_loop_shape_differs_from_preisach(family):
    """Same stroke and width, another shape: the noise-free 1 Hz loops of the clean benches, each
    scaled to its own stroke, differ from Preisach's by (measured, Y/Z) 1.4/1.4 % of the stroke for
    Bouc–Wen and 1.0/1.3 % for Maxwell-slip, some 30x the 3 nm gauge noise."""
    grid = np.linspace(2.0, 118.0, 300)
    n = int(FS)

    def shape(u, x):
        return (np.concatenate(_branches(u[-n:], x[-n:], grid)) - x[-n:].min()) / np.ptp(x[-n:])

    ref_u, ref_x = _true_x("base", 1.0, 2)
    u, x = _true_x(CLEAN[family], 1.0, 2)
    for a in (0, 1):
        assert np.max(np.abs(shape(u[:, a], x[:, a]) - shape(ref_u[:, a], ref_x[:, a]))) > 0.007, a


@pytest.mark.parametrize("family", FAMILIES)
def test_the_family_itself_is_rate_and_sample_rate_independent(family):
    """Clean bench (relaxation, creep, dynamics and bandwidths off), noise off: the last cycle at
    10 Hz and at 100 Hz (sampled at 20 kHz or at 5 kHz) against the 1 Hz cycle at the same drive
    phases (the same voltages, no interpolation). Measured: ≤ 4e-9 µm for Bouc–Wen (RK4 in 1 V
    substeps), ≤ 3e-14 µm for Preisach and Maxwell-slip (integrated exactly); the gauge noise is 3 nm."""
    loops = {}
    for f_hz, fs in ((1.0, FS), (10.0, FS), (100.0, FS), (100.0, 5000.0)):
        _, x = _true_x(CLEAN[family], f_hz, 3, fs)
        loops[f_hz, fs] = x[-int(round(fs / f_hz)) :]
    slow = loops[1.0, FS]
    for (f_hz, fs), x in loops.items():
        stride = int(round(FS / fs * f_hz))
        assert np.max(np.abs(x - slow[::stride])) < 1e-6, (f_hz, fs)


def _minor_loop_closure_nm(bench: str) -> list[float]:
    """Up to 100 V, down to 40 V, then four 40–70–40 V minor loops: the true Y position back at
    40 V after each, minus the position before the first (nm)."""
    up, down = np.linspace(0, 100, 4000), np.linspace(100, 40, 2400)
    minor = np.concatenate([np.linspace(40, 70, 1200), np.linspace(70, 40, 1200)])
    seq = np.concatenate([up, down] + [minor] * 4)
    b = open_bench(bench, seed=0, overrides=NOISELESS)
    b.parts.daq.write_read(np.column_stack([seq / 20.0, seq / 20.0]))
    x = b.parts.world.last_diag[:, K.D_X_Y]
    i0 = len(up) + len(down) - 1
    return [1e3 * (x[i0 + k * len(minor)] - x[i0]) for k in range(1, 5)]


def test_preisach_minor_loops_close_exactly():
    """Return-point memory: a minor loop returns to its start (wiping-out), to rounding."""
    assert max(abs(c) for c in _minor_loop_closure_nm("base")) < 1e-6


@pytest.mark.parametrize("family", ["bouc_wen", "maxwell_slip"])
def test_other_families_minor_loops_do_not_close_and_settle(family):
    """No return-point memory: the first 40–70–40 V minor loop ends below its start and the next
    ones settle onto a stable loop (accommodation). Measured (nm after loops 1..4): Bouc–Wen
    −131, −144, −145, −145; Maxwell-slip −59, −71, −75, −76."""
    c = _minor_loop_closure_nm(CLEAN[family])
    assert 20.0 < abs(c[0]) < 400.0
    assert abs(c[3] - c[2]) < 0.1 * abs(c[0])


@pytest.fixture(scope="module")
def clean_pi_rms():
    return {family: sweep_pi_rms(CLEAN[family]) for family in FAMILIES}


def test_static_pi_misfit_per_family(clean_pi_rms):
    """Static-PI RMS left on each clean bench's characterisation sweep (sweep_pi_rms: 1, 10, 50,
    100 Hz, each axis alone). Measured, both axes, with the non-Preisach families switching on the
    amplifier's noise-free output: Preisach 0.0102 µm, Bouc–Wen about 2× that, Maxwell-slip 0.0089 µm
    (its smooth elements with spread slip limits are the nearest to a PI: the static PI fits it as
    well as Preisach; its loop is still not a PI loop, test_family_loop_shape_differs_from_preisach).
    3 nm of each figure is gauge noise."""
    base = clean_pi_rms["preisach"]["both"]
    assert clean_pi_rms["bouc_wen"]["both"] > 1.6 * base
    assert 0.6 * base < clean_pi_rms["maxwell_slip"]["both"] < 1.4 * base


@pytest.mark.slow
@pytest.mark.parametrize(
    "bench",
    [
        PREFIX[f] + e
        for f in FAMILIES
        for e in EFFECTS
        if f != "preisach" or e in ("sensor_nonlinearity", "temperature")
    ],
)
def test_each_variant_leaves_more_than_twice_the_base_pi_error(bench, clean_pi_rms):
    """Every hidden-effect bench of every family leaves ≥ 2× the static-PI RMS of base.toml (the
    Preisach variants of before are checked in test_emulator_calibration.py)."""
    assert sweep_pi_rms(bench)["both"] >= 2.0 * clean_pi_rms["preisach"]["both"]


def test_family_benches_stand_on_their_variant_and_family():
    cfg = load_config("bw_creep")
    y = cfg["axes"]["y"]["piezo"]
    assert y["hysteresis"]["family"] == "bouc_wen" and y["creep"]["enabled"]
    assert not cfg["daq"]["latency"]["enabled"] and not y["rate_dependence"]["enabled"]  # base's, not default's
    ms = load_config("ms_temperature")
    assert ms["axes"]["z"]["piezo"]["hysteresis"]["family"] == "maxwell_slip"
    assert ms["ambient"]["drift"]["cycle_amplitude_c"] == 5.0 and ms["axes"]["z"]["piezo"]["temperature"]["enabled"]
    assert load_config("sensor_nonlinearity")["axes"]["y"]["gauge"]["nonlinearity"]["enabled"]


def test_family_keys_are_validated_by_name():
    with pytest.raises(ValueError, match=r"axes\.y\.piezo\.hysteresis\.family: must be a string \(one of preisach"):
        load_config("base", {"axes.y.piezo.hysteresis.family": "jiles_atherton"})
    with pytest.raises(ValueError, match=r"axes\.z\.piezo\.hysteresis\.bouc_wen\.hysteretic_gain: 0\.7 exceeds"):
        load_config("bw_base", {"axes.z.piezo.hysteresis.bouc_wen.hysteretic_gain": 0.7})
    with pytest.raises(ValueError, match=r"axes\.y\.piezo\.hysteresis\.maxwell_slip\.elements: 1000 is outside"):
        load_config("ms_base", {"axes.y.piezo.hysteresis.maxwell_slip.elements": 1000})
    with pytest.raises(ValueError, match=r"axes\.y\.piezo\.hysteresis\.bouc_wen\.lag_saturatoin_v: unknown key"):
        load_config("bw_base", {"axes.y.piezo.hysteresis.bouc_wen.lag_saturatoin_v": 10.0})


def test_the_temperature_bench_records_temp_c_and_the_gain_follows_it():
    """temperature.toml: the record carries temp_c (its thermometer), which swings 22–27 °C over
    10 s; the stroke of each 1 Hz cycle follows at the configured 0.4 %/K (measured 0.0039 per K)."""
    u = signals.biased_sine(1.0, 10, FS, 0.0, 120.0).value
    rec = open_bench("temperature", seed=0).run({"y": u, "z": u}, FS)
    temp, x = rec.extra["temp_c"], rec.x_um["y"]
    assert len(temp) == rec.samples
    assert temp.min() == pytest.approx(22.0, abs=0.01) and temp.max() == pytest.approx(27.0, abs=0.01)
    n = int(FS)
    strokes = np.array([np.ptp(x[k * n : (k + 1) * n]) for k in range(1, 10)])
    temps = np.array([temp[k * n : (k + 1) * n].mean() for k in range(1, 10)])
    slope = np.polyfit(temps - 22.0, strokes / strokes.mean(), 1)[0]
    assert slope == pytest.approx(0.004, rel=0.15)
    assert "temp_c" not in open_bench("default", seed=0).run({"y": u[:2000]}, FS).extra  # no thermometer
