"""The noise floor and the period on imported data whose drive does not repeat everywhere: bursts
with amplitude ramps and a hold (like fixtures/real/yan9a-dbo/Test_Vi_Do_Di.dat)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from service.science.data.record import Record
from service.science.data.signals import dominant_period_samples
from service.science.discovery.diagnosis import diagnose
from service.science.discovery.noise import repeatability
from tests.support.realdata import REAL_DIR

PERIOD = 200.0  # samples per cycle


def burst_drive(rng=None) -> tuple[np.ndarray, np.ndarray]:
    """Drive (V) and its amplitude envelope: 6 steady cycles, 12 ramping down, a 1300-sample hold,
    12 ramping up, 6 steady: most successive cycles differ in amplitude."""
    env = np.concatenate(
        [np.ones(1200), np.linspace(1, 0, 2400), np.zeros(1300), np.linspace(0, 1, 2400), np.ones(1200)]
    )
    t = np.arange(env.size)
    phase = np.where(np.arange(env.size) < 4900, 0.0, 0.7)  # the burst after the hold restarts in phase 0.7
    return 1.8 + 1.6 * env * np.sin(2 * np.pi * t / PERIOD + phase), env


def test_period_ignores_a_hold_and_ramps():
    u, _ = burst_drive()
    assert abs(dominant_period_samples(u) / PERIOD - 1) < 0.005


def test_noise_counts_only_cycles_whose_drive_repeated():
    rng = np.random.default_rng(0)
    u, env = burst_drive()
    sigma = 0.01
    t = np.arange(u.size)
    # a residual that depends on the amplitude (a model error, repeatable for a given drive) plus noise
    residual = 1.0 * env * np.sin(4 * np.pi * t / PERIOD) + sigma * rng.standard_normal(u.size)
    blind = repeatability(residual, PERIOD)["noise_um"]
    matched = repeatability(residual, PERIOD, drive=u)
    assert abs(matched["noise_um"] / sigma - 1) < 0.15
    assert matched["method"] == "cycle-to-cycle repeatability"
    assert blind > 1.5 * sigma  # counting every pair, the ramps pass for noise
    # a drive that never repeats (a chirp): second differences instead
    chirp = np.sin(2 * np.pi * np.cumsum(np.linspace(1 / 400, 1 / 100, 6000)))
    fallback = repeatability(sigma * rng.standard_normal(6000), PERIOD, drive=chirp)
    assert fallback["cycles"] == 0 and "second differences" in fallback["method"]
    assert abs(fallback["noise_um"] / sigma - 1) < 0.15


@pytest.mark.slow
def test_real_bursts_with_a_hold_get_the_same_noise_floor_as_the_steady_file():
    data = np.loadtxt(REAL_DIR / "yan9a-dbo" / "Test_Vi_Do_Di.dat")[:11152]  # before the authors' inverse
    record = Record(data[:, 0], data[:, 4], 200.0, label="Test_Vi_Do_Di", hold_out=True)
    assert abs(record.period_samples(record.splits[0]) / 200.0 - 1) < 0.01
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = diagnose([record])
    assert 0.03 < d["noise_floor_um"] < 0.12  # Model_Vi_Do.dat: about 0.066 µm
    assert d["noise"]["source"] == "rests"  # its 10 s of rests: 0.063 µm
    # no verdict on the loop's symmetry: neither block's drive is a point-symmetric repeated cycle (the
    # symmetry test's premise), so sensor_nonlinearity is no longer claimed from its 224 nm even part
    assert not d["at_noise_floor"]
    assert d["held_out_to_noise"] > 3


@pytest.mark.slow
def test_the_diagnosis_does_not_depend_on_the_drives_origin_or_units_or_the_gauges_sign():
    """Other labs' files: a bipolar or negative amplifier input, millivolts, a gauge reading against
    the drive. The composite model counts from the lowest drive and fits sign·x, so the diagnosis is
    the same as for the file as recorded."""
    data = np.loadtxt(REAL_DIR / "yan9a-dbo" / "Model_Vi_Do.dat")
    u, x = data[:, 0], data[:, 4]
    results = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for drive, response in ((u, x), (u - 1.8, x), (u - 4.0, x), (1000 * u, x), (u, -x)):
            d = diagnose([Record(drive, response, 200.0, label="variant", hold_out=True)])
            results.append(
                (
                    d["residual_rms_um"],
                    d["noise_floor_um"],
                    {c["effect"]: c["score"] for c in d["candidates"]},
                    [c["effect"] for c in d["candidates"]],
                )
            )
    rms, floor, scores, order = results[0]
    for other in results[1:]:
        assert other[0] == pytest.approx(rms, rel=1e-6) and other[1] == pytest.approx(floor, rel=1e-6)
        assert other[3] == order
        # the rate columns' segment (sign of u̇, ü) flips at the flat turning points with the last bits
        assert all(abs(other[2][e] - scores[e]) < 0.005 for e in scores), (other[2], scores)


def _loop(period: float, cycles: int, cornered: bool) -> np.ndarray:
    """A periodic signal (µm, 1 µm peak to peak): with corners, as a hysteresis residual has at each
    reversal and threshold (|sin| of the phase), or smooth (a few harmonics)."""
    phase = np.pi * np.arange(int(cycles * period)) / period
    return np.abs(np.sin(phase)) if cornered else 0.5 * np.sin(2 * phase) + 0.1 * np.sin(6 * phase + 1.0)


@pytest.mark.parametrize("period, cornered", [(500 / 13, True), (976.5625, True), (500 / 13 * 1.0003, False)])
def test_a_fractional_period_gives_the_noise_and_no_more(period, cornered):
    """38.46 samples a cycle (130 Hz at 5 kHz), 976.5625 (10 Hz at 9765.625 Hz): cycles fall on other
    sample phases. Resampled linearly they read 19 % of the noise away; resampled at all, a loop's
    corners interpolate differently in each cycle (8 nm of 'noise' from a noise-free loop here).
    Cycles a whole number of samples apart are compared sample with sample (13 and 16 cycles);
    without such a distance (the last period), a windowed sinc resamples them, with its noise gain."""
    sigma = 0.003
    clean = _loop(period, 60, cornered)
    noisy = clean + sigma * np.random.default_rng(1).standard_normal(clean.size)
    assert repeatability(noisy, period)["noise_um"] == pytest.approx(sigma, rel=0.08)
    assert repeatability(clean, period)["noise_um"] < (1e-9 if cornered else 5e-4)  # µm


def test_a_record_without_noise_gets_a_verdict_in_words_not_nan():
    """A simulated record (another lab's model output, imported as a user did over REST: 1 Hz at
    1 kHz, every cycle the same to the last digit) has no noise to measure in any block: the verdict
    said "up to nan× a block's own noise"."""
    from service.science.data.segmentation import blocks_without_table
    from service.science.discovery.diagnosis import diagnose
    from service.science.discovery.records import records_from_arrays

    t = np.arange(4000) / 1000.0
    u = np.round(50 - 50 * np.cos(2 * np.pi * t), 4)  # as written in the file: 0.1 mV,
    x = np.round(0.12 * u - 1.2 * np.sin(2 * np.pi * t), 6)  # 1 pm
    record = records_from_arrays(
        {"u_y_v": u, "x_y_um": x}, 1000.0, blocks_without_table({"y": u}, 1000.0), ("y",), "simulated:"
    )[0]
    d = diagnose([record])
    assert d["noise_floor_um"] < 1e-9 and d["verdict"] == "complete" and not d["at_noise_floor"]
    assert "nan" not in d["verdict_text"] and "no block's own noise could be measured" in d["verdict_text"]
