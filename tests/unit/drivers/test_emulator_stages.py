"""Per-stage physics of the emulated bench, each asserted with numbers.

Most tests drive the emulated DAQ directly (DAQ volts) and read the world's diagnostics
(``world.last_diag``: quantised AO, amplifier output, current, true tool displacement).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from drivers.emulated import kernels as K
from drivers.emulated import load_config
from drivers.factory import open_bench
from drivers.interfaces import LimitError

FS = 20000.0
LSB = 20.0 / 2**16


def ramp_to(v0_daq: float, v1_daq: float, n: int) -> np.ndarray:
    return np.linspace(v0_daq, v1_daq, n)


def sine_fit(x: np.ndarray, f: float, fs: float) -> float:
    """Amplitude of the f component of x by least squares (offset removed)."""
    t = np.arange(len(x)) / fs
    a = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t)])
    c, *_ = np.linalg.lstsq(a, x, rcond=None)
    return float(np.hypot(c[0], c[1]))


# ---------------------------------------------------------------------------------- DAQ
def test_ao_and_ai_are_16_bit_codes():
    bench = open_bench("default", seed=1)
    daq, world = bench.parts.daq, bench.parts.world
    ao = np.column_stack([np.linspace(0.0, 0.01, 4001), np.linspace(0.0, -0.01, 4001)])  # fractions of an LSB
    ai = daq.write_read(ao)
    q = world.last_diag[:, [K.D_AO_Y, K.D_AO_Z]]
    codes = q / LSB
    assert np.allclose(codes, np.round(codes), atol=1e-9)
    steps = np.unique(np.round(np.abs(np.diff(q[:, 0])), 15))
    assert steps.max() == pytest.approx(LSB, rel=1e-12)  # exactly 20 V / 2**16
    assert np.max(np.abs(q - ao)) <= LSB / 2 + 1e-15
    ai_codes = ai / LSB
    assert np.allclose(ai_codes, np.round(ai_codes), atol=1e-9)
    assert np.max(np.abs(ai)) <= 10.0


def test_sample_clock_is_coerced_to_the_100_mhz_timebase():
    bench = open_bench("default", seed=0)
    daq = bench.parts.daq
    assert daq.configure(30000.0) == pytest.approx(100e6 / 3333, rel=1e-15)
    assert daq.sample_rate_hz == pytest.approx(30003.0003, rel=1e-9)
    assert daq.configure(20000.0) == 20000.0
    assert daq.configure(7.0) == 100e6 / round(100e6 / 7.0)
    with pytest.raises(LimitError, match="exceeds"):
        daq.configure(1e6)
    with pytest.raises(LimitError):
        daq.configure(-5.0)


@pytest.mark.parametrize("samples", [1, 3])
def test_latency_shifts_ai_by_the_configured_samples(samples):
    t = np.arange(4000) / FS
    ao = np.column_stack([2.0 + 1.5 * np.sin(2 * np.pi * 37 * t) + 0.5 * np.sin(2 * np.pi * 211 * t)] * 2)
    outs = {}
    for lat in (0, samples):
        b = open_bench("default", seed=5, overrides={"daq.latency.samples": lat})
        outs[lat] = b.parts.daq.write_read(ao)
    errs = [np.sqrt(np.mean((outs[samples][s : 3900 + s, :] - outs[0][:3900, :]) ** 2)) for s in range(8)]
    assert int(np.argmin(errs)) == samples
    assert errs[samples] < 0.2 * min(e for s, e in enumerate(errs) if s != samples)


# ---------------------------------------------------------------------------------- amplifier
@pytest.mark.parametrize("over", [1.05, 2.0])
def test_current_limit_clips_slope_and_latches_fault_when_overdriven(over):
    bench = open_bench("default", seed=2)
    daq, world, amp = bench.parts.daq, bench.parts.world, bench.parts.amplifiers["y"]
    f_max = amp.current_limit_a / (math.pi * amp.load_capacitance_f * 120.0)
    assert f_max == pytest.approx(294.7, abs=0.1)
    f = over * f_max
    t = np.arange(int(0.1 * FS)) / FS
    u = 60.0 - 60.0 * np.cos(2 * np.pi * f * t)
    ao = np.column_stack([u / 20.0, np.zeros_like(u)])
    daq.write_read(ao)
    d = world.last_diag
    i_y = d[:, K.D_I_Y]
    assert np.max(np.abs(i_y)) <= amp.current_limit_a * (1 + 1e-9)
    assert np.max(np.abs(i_y)) == pytest.approx(amp.current_limit_a, rel=1e-6)  # it did clip
    slope = np.max(np.abs(np.diff(d[:, K.D_VP_Y]))) * FS  # includes ~2 mV rms output noise
    assert slope < amp.current_limit_a / amp.load_capacitance_f + 0.02 * FS
    assert np.max(np.abs(np.diff(u))) * FS > (over - 0.01) * amp.current_limit_a / amp.load_capacitance_f
    st = amp.status()
    assert st.fault and "over-current" in st.fault_reason and "mA" in st.fault_reason and "ms" in st.fault_reason
    daq.write_read(np.zeros((int(0.01 * FS), 2)))  # a latched fault holds the output at 0 V
    assert abs(amp.status().output_v) < 0.05
    amp.clear_fault()
    assert not amp.status().fault


def test_no_fault_below_the_current_limit_frequency():
    bench = open_bench("default", seed=2)
    daq, amp = bench.parts.daq, bench.parts.amplifiers["z"]
    t = np.arange(int(0.05 * FS)) / FS
    u = 60.0 - 60.0 * np.cos(2 * np.pi * 250.0 * t)  # 85 % of f_max
    daq.write_read(np.column_stack([np.zeros_like(u), u / 20.0]))
    assert not amp.status().fault
    assert bench.parts.world.peak_current_a()["z"] == pytest.approx(math.pi * 250 * 120 * 1.8e-6, rel=0.1)


def test_amplifier_small_signal_bandwidth():
    bench = open_bench("default", seed=3)
    daq = bench.parts.daq
    fs = daq.configure(200000.0)
    bw = load_config("default")["axes"]["y"]["amplifier"]["bandwidth"]["bandwidth_hz"]
    daq.write_read(np.column_stack([ramp_to(0, 3.0, 2000), ramp_to(0, 3.0, 2000)]))
    freqs = np.array([200.0, 2000.0, 3500.0, 5000.0, 6500.0, 8000.0])
    gains = []
    for f in freqs:
        t = np.arange(int(0.02 * fs)) / fs
        ao = 3.0 + 0.025 * np.sin(2 * np.pi * f * t)  # 60 V ± 0.5 V at the actuator
        ai = daq.write_read(np.column_stack([ao, ao]))
        gains.append(sine_fit(ai[400:, 2], f, fs) / 0.05 / 0.025 / 20.0)  # monitor ratio 0.05, gain 20
    gains = np.array(gains)
    assert gains[0] == pytest.approx(1.0, abs=0.02)
    f3db = float(np.interp(-1.0 / math.sqrt(2), -gains, freqs))
    assert abs(f3db - bw) / bw < 0.10


# ---------------------------------------------------------------------------------- piezo
def _hold_run(overrides, v_act: float, seconds: float, seed=4):
    bench = open_bench("default", seed=seed, overrides=overrides)
    n = int(seconds * FS)
    u = np.full(n, v_act)
    u[:40] = np.linspace(0, v_act, 40)
    return bench, bench.run({"y": u, "z": u}, FS)


def test_creep_grows_per_decade_as_configured():
    quiet = {"ambient.drift.enabled": False, "axes.*.gauge.drift.enabled": False}
    _, rec = _hold_run(quiet, 60.0, 10.2)
    rate = load_config("default")["axes"]["y"]["piezo"]["creep"]["rate_per_decade"]
    for axis in ("y", "z"):
        x = rec.x_um[axis]
        at = {t: x[int(t * FS) - 100 : int(t * FS) + 100].mean() for t in (0.1, 1.0, 10.0)}
        per_decade = (at[10.0] - at[0.1]) / 2.0 / at[0.1]
        assert 0.01 <= per_decade <= 0.02
        assert per_decade == pytest.approx(rate, rel=0.2)
        assert (at[1.0] - at[0.1]) == pytest.approx(at[10.0] - at[1.0], rel=0.25)  # log(t), not linear


def test_temperature_raises_gain_by_the_configured_coefficient():
    t = np.arange(int(3 * FS / 10)) / FS
    u = 60 - 60 * np.cos(2 * np.pi * 10 * t)
    x = {}
    for temp in (22.0, 32.0):
        b = open_bench("default", seed=6, overrides={"ambient.temperature_c": temp, "ambient.drift.enabled": False})
        x[temp] = b.run({"y": u, "z": u}, FS).x_um
    coeff = load_config("default")["axes"]["y"]["piezo"]["temperature"]["gain_per_c"]
    for axis in ("y", "z"):
        k = np.polyfit(x[22.0][axis], x[32.0][axis], 1)[0]
        assert (k - 1.0) / 10.0 == pytest.approx(coeff, rel=0.1)


def test_hysteresis_loop_closes_and_dither_does_not_erase_memory():
    quiet = {"axes.*.piezo.creep.enabled": False, "ambient.drift.enabled": False, "axes.*.gauge.drift.enabled": False}
    bench = open_bench("default", seed=7, overrides=quiet)
    world = bench.parts.world
    up = np.linspace(0, 100, 4000)
    down = np.linspace(100, 40, 2400)
    minor = np.concatenate([np.linspace(40, 70, 1200), np.linspace(70, 40, 1200)])
    seq = np.concatenate([up, down, minor, np.full(8000, 40.0)])
    ai = bench.parts.daq.write_read(np.column_stack([seq / 20.0, seq / 20.0]))
    x = world.last_diag[:, K.D_X_Y]
    i0 = len(up) + len(down) - 1  # at 40 V, descending from 100 V
    i1 = i0 + len(minor)  # back at 40 V after a 40-70-40 V loop
    assert x[i1] == pytest.approx(x[i0], abs=0.004)  # minor loop closes (wiping out)
    assert abs(x[-1] - x[i1]) < 0.004  # 0.4 s of 2 mV noise: memory kept
    rising_40 = x[np.argmin(np.abs(up - 40.0))]
    assert x[-1] - rising_40 > 0.2  # hysteresis: above the rising branch
    assert ai.shape == (len(seq), 4)


# ---------------------------------------------------------------------------------- flexure
def test_flexure_resonances_from_a_broadband_response():
    bench = open_bench("default", seed=8)
    daq, world = bench.parts.daq, bench.parts.world
    rng = np.random.default_rng(0)
    n = int(8 * FS)
    daq.write_read(np.column_stack([ramp_to(0, 3.0, 400), ramp_to(0, 3.0, 400)]))
    ao = 3.0 + 0.02 * rng.standard_normal((n, 2))
    ai = daq.write_read(ao)
    vp = world.last_diag[:, [K.D_VP_Y, K.D_VP_Z]]
    for a, (axis, f_n) in enumerate((("y", 482.6), ("z", 290.7))):
        f, pxy = signal.csd(vp[:, a], ai[:, a], fs=FS, nperseg=16384)
        _, pxx = signal.welch(vp[:, a], fs=FS, nperseg=16384)
        h = np.abs(pxy / pxx)
        band = (f > 150) & (f < 800)
        k = np.flatnonzero(band)[np.argmax(h[band])]
        y0, y1, y2 = np.log(h[k - 1 : k + 2])
        peak = f[k] + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2) * (f[1] - f[0])
        assert abs(peak - f_n) / f_n < 0.02, axis
        assert h[k] / np.median(h[(f > 20) & (f < 60)]) > 4.0  # a real resonance peak


def test_cross_coupling_matches_configuration():
    bench = open_bench("default", seed=9)
    t = np.arange(int(5 * FS / 10)) / FS
    u = 60 - 60 * np.cos(2 * np.pi * 10 * t)
    rec = bench.run({"z": u}, FS)  # Y held at 0 V
    k = np.polyfit(rec.x_um["z"], rec.x_um["y"], 1)[0]
    assert k == pytest.approx(0.01, rel=0.1)


# ---------------------------------------------------------------------------------- gauges
def test_gauge_noise_rms_at_zero_drive():
    bench = open_bench("default", seed=10)
    ai = bench.parts.daq.write_read(np.zeros((int(FS), 2)))
    for a, scale in ((0, 1.0), (1, 2.0)):
        x_nm = ai[:, a] * scale * 1e3
        t = np.arange(len(x_nm))
        resid = x_nm - np.polyval(np.polyfit(t, x_nm, 1), t)
        assert np.std(resid) == pytest.approx(3.0, rel=0.2)


def test_gauge_nonlinearity_against_true_displacement():
    quiet = {
        "axes.*.gauge.noise.enabled": False,
        "axes.*.amplifier.noise.enabled": False,
        "axes.*.gauge.bandwidth.enabled": False,
        "axes.*.gauge.drift.enabled": False,
    }
    bench = open_bench("default", seed=11, overrides=quiet)
    u = 60 - 60 * np.cos(2 * np.pi * np.arange(int(FS / 2)) / (FS / 2))
    ai = bench.parts.daq.write_read(np.column_stack([u / 20, u / 20]))
    d = bench.parts.world.last_diag
    for a, scale in ((0, 1.0), (1, 2.0)):
        true = d[:, K.D_X_Y + a]
        s = true / (10 * scale)
        basis = np.column_stack([1.5 * math.sqrt(3) * (s**3 - s), np.ones_like(s)])
        c, *_ = np.linalg.lstsq(basis, ai[:, a] * scale - true, rcond=None)
        assert c[0] == pytest.approx(0.0005 * 20 * scale, rel=0.1)  # 0.05 % of the full span


def test_gauge_offset_drift_is_visible_over_ten_seconds():
    bench = open_bench("drift", seed=12)
    ai = bench.parts.daq.write_read(np.zeros((int(10 * FS), 2)))
    t = np.arange(len(ai)) / FS
    for a, scale in ((0, 1.0), (1, 2.0)):
        slope_nm_s = np.polyfit(t, ai[:, a] * scale * 1e3, 1)[0]
        assert slope_nm_s == pytest.approx(20.0, rel=0.1)


def test_gauge_saturation_is_reported():
    from drivers.record import RunInterrupted

    bench = open_bench("default", seed=13, overrides={"axes.y.gauge.scale_um_per_v": 0.4})  # ±4 µm
    t = np.arange(int(FS / 10)) / FS
    with pytest.raises(RunInterrupted, match="saturated") as info:
        bench.run({"y": 60 - 60 * np.cos(2 * np.pi * 10 * t)}, FS, block_samples=500)
    assert info.value.record.partial
    st = bench.parts.sensors["y"].status()
    assert not st.ok and st.saturated and "±10 V" in st.reason
