"""Benchmark: exact least squares vs the paper's PSO on the same dynamic-PI data, in one run.

    python -m service.perf.identification [seed]

Ground truth: a dynamic PI with the paper's Y-axis weights (Table 2) and rate parameters
(Table 4, read with u̇ in V/ms and ü in V/ms², i.e. ×1e-3 and ×1e-6 in SI), driven by a
0–120 V biased sine at 1/10/50/100 Hz (5 cycles, 20 kHz), plus Gaussian sensor noise.
Both fits start from the same Records; numba kernels are compiled in a warm-up first.
On a shared machine, OpenBLAS's threads contend with other work and slow the small
factorisations of the LS far more than the PSO's products: compare runs with the same
``OPENBLAS_NUM_THREADS`` (reported in the result).
"""

from __future__ import annotations

import json
import os
import sys
import time

import numpy as np
from scipy.signal import lfilter

from service.science.data.record import Record
from service.science.data.signals import biased_sine
from service.science.fitting.metrics import fit_metrics, rms
from service.science.models import DynamicPI, StaticPI, equal_thresholds
from service.science.models.procedures import fit_dynamic_pi_pso, fit_dynamic_pi_two_stage

FREQUENCIES_HZ = (1.0, 10.0, 50.0, 100.0)
SAMPLE_RATE_HZ = 20_000.0
CYCLES = 5
NOISE_RMS_UM = 0.005
PAPER_WEIGHTS_Y_UM_PER_V = [
    0.01354,
    0.02790,
    4.3634e-8,
    0.004014,
    0.007765,
    3.3995e-14,
    6.8298e-13,
    8.9564e-13,
    8.0574e-13,
    7.0060e-15,
]
PAPER_ALPHA_Y = [-8.4632e-7, -3.9336e-6, 1.4926e-6, -3.0164e-6]  # µm·ms/V²
PAPER_BETA_Y = [2.5880e-7, 9.6875e-7, 2.1025e-6, 1.3017e-6]  # µm·ms²/V²


def static_truth() -> StaticPI:
    """The paper's Y-axis static PI (Table 2), thresholds 0, 6, …, 54 V, no offset."""
    model = StaticPI(thresholds_v=equal_thresholds(120.0, 10))
    model.weights_um_per_v = np.array(PAPER_WEIGHTS_Y_UM_PER_V)
    model.offset_um = 0.0
    return model


def ground_truth() -> DynamicPI:
    """The synthetic plant: the static truth plus the paper's Y-axis α, β in SI units."""
    model = DynamicPI.from_static(static_truth())
    model.alpha_um_per_v2_s = np.array(PAPER_ALPHA_Y) * 1e-3
    model.beta_um_per_v2_s2 = np.array(PAPER_BETA_Y) * 1e-6
    return model


def paper_drives() -> list[Record]:
    """The paper's four loops as commanded (exact derivatives attached), no displacement."""
    return [Record.from_waveform(biased_sine(f, CYCLES, SAMPLE_RATE_HZ), label=f"{f:g} Hz") for f in FREQUENCIES_HZ]


def synthetic_loops(truth: DynamicPI, seed: int = 0, noise_rms_um: float = NOISE_RMS_UM) -> list[Record]:
    """Noisy records of ``truth`` for the paper's four loops (commanded derivatives attached)."""
    rng = np.random.default_rng(seed)
    return [d.with_x(truth.predict(d) + rng.normal(0.0, noise_rms_um, d.n_samples)) for d in paper_drives()]


def lagged_pi_loops(tau_s: float = 3e-4, seed: int = 0, noise_rms_um: float = 0.0) -> list[Record]:
    """Rate dependence NOT of the dynamic-PI form: the static PI driven through a first-order
    lag y_k = a·y_{k−1} + (1−a)·u_k, a = exp(−T/``tau_s``) (at rest at 0 V), same four loops."""
    pi = static_truth()
    a = np.exp(-1.0 / (SAMPLE_RATE_HZ * tau_s))
    rng = np.random.default_rng(seed)
    return [
        d.with_x(pi.predict(lfilter([1.0 - a], [1.0, -a], d.u_v)) + rng.normal(0.0, noise_rms_um, d.n_samples))
        for d in paper_drives()
    ]


def _timed(fn):
    t0 = time.perf_counter()
    result = fn()
    return time.perf_counter() - t0, result


def _overall_rms(model, data) -> float:
    """RMS over all samples of all records (the paper's eq. 12)."""
    return rms(np.concatenate([s.x_um - model.predict(s) for s in data]))


def run_identification_benchmark(seed: int = 0, repeats: int = 3) -> dict:
    """Time (median of ``repeats`` interleaved runs) and score the exact joint LS and the paper's
    PSO on the same data."""
    truth = ground_truth()
    data = synthetic_loops(truth, seed)
    DynamicPI().fit(data)  # warm-up: numba compilation and first-touch costs
    fit_dynamic_pi_pso(data, seed=seed, n_iterations=2)

    ls_times, pso_times = [], []
    for _ in range(repeats):  # interleaved, so both see the same machine load
        t, ls = _timed(lambda: DynamicPI().fit(data))
        ls_times.append(t)
        t, (pso, pso_result) = _timed(lambda: fit_dynamic_pi_pso(data, seed=seed))
        pso_times.append(t)
    ls_s, pso_s = float(np.median(ls_times)), float(np.median(pso_times))
    two_stage = fit_dynamic_pi_two_stage(data)

    per_frequency = {
        s.label: {
            "ls_rms_um": fit_metrics(s.x_um, ls.predict(s))["rms_um"],
            "pso_rms_um": fit_metrics(s.x_um, pso.predict(s))["rms_um"],
            "truth_rms_um": fit_metrics(s.x_um, truth.predict(s))["rms_um"],
        }
        for s in data
    }
    rate_true = np.concatenate([truth.alpha_um_per_v2_s, truth.beta_um_per_v2_s2])

    def rate_error(m):
        est = np.concatenate([m.alpha_um_per_v2_s, m.beta_um_per_v2_s2])
        return float(np.max(np.abs(est - rate_true) / np.abs(rate_true)))

    return {
        "ls_s": ls_s,
        "pso_s": pso_s,
        "speedup": pso_s / ls_s,
        "ls_rms_um": _overall_rms(ls, data),
        "pso_rms_um": _overall_rms(pso, data),
        "two_stage_rms_um": _overall_rms(two_stage, data),
        "truth_rms_um": _overall_rms(truth, data),
        "ls_rate_params_max_rel_error": rate_error(ls),
        "pso_rate_params_max_rel_error": rate_error(pso),
        "pso_final_cost_um": pso_result.cost,
        "pso_evaluations": pso_result.n_evaluations,
        "per_frequency": per_frequency,
        "n_samples": int(sum(s.n_samples for s in data)),
        "noise_rms_um": NOISE_RMS_UM,
        "seed": seed,
        "repeats": repeats,
        "cpu_count": os.cpu_count(),
        "openblas_num_threads": os.environ.get("OPENBLAS_NUM_THREADS", "default"),
    }


if __name__ == "__main__":
    print(json.dumps(run_identification_benchmark(int(sys.argv[1]) if len(sys.argv) > 1 else 0), indent=2))
