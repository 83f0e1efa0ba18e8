"""Load (issue 9 §6): a short run of the `evcbench bench service` harness.

50 requests/s on the status and data endpoints for 5 s while a real-time trajectory job runs on the
emulated bench (DAQ paced to the sample clock). Asserted: every request answered without error, the
load was delivered, and the job kept real time (no overrun) and succeeded. No latency assertion:
machines are noisy; the latency figures are the benchmark's (README, "Fuzz and load"). The overrun
count is a timing property too: a block is late when the loop hands it over more than two blocks
(20 ms) after its slot, which a host saturated by other processes can still cause (7 of ~700 seen
with a load average of 6 on 2 cores). So the test bounds it at 2 % of the periods — a loop that
starved under the requests would miss far more — and the benchmark reports the exact count
(0 of 6207 over 60 s on a quiet machine).
"""
from __future__ import annotations

from service.perf.service_load import run_service_benchmark

DURATION_S = 5.0
RATE_HZ = 50.0


def test_trajectory_keeps_real_time_under_50_requests_per_second():
    result = run_service_benchmark(duration_s=DURATION_S, rate_hz=RATE_HZ)
    assert result["errors"] == 0, result
    assert result["requests"] == round(DURATION_S * RATE_HZ), result  # every request answered without error
    assert result["achieved_rate_hz"] >= 0.95 * RATE_HZ, result
    assert result["realtime"] is True
    assert result["job_state"] == "succeeded", result
    # 100 Hz: one paced block per period for the whole load (+2 s of margin) and its start ramps
    assert result["job_periods"] >= (DURATION_S + 2.0) * 100, result
    assert result["job_overruns"] <= 0.02 * result["job_periods"], result
