"""The loop's software watchdog (drivers/watchdog.py) judges only time it watched: a process stopped
whole (SIGSTOP) and resumed does not trip it, since its loop was paused, not stalled; a loop that
stalls by itself still trips it after its timeout."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

from tests.support.live_server import ROOT

#: a loop fed every 10 ms under a 0.3 s watchdog; after ``stall_after_s`` (if given) it stops feeding
CHILD = """
import json, sys, threading, time
from drivers.watchdog import SafetyConfig, Watchdog

class Daq:
    idle = 0
    def write_idle(self):
        Daq.idle += 1

stall_after_s = float(sys.argv[1])
trips = []
dog = Watchdog(Daq(), SafetyConfig(watchdog_periods=1, watchdog_min_s=0.3, watchdog_poll_s=0.005), trips.append)
dog.arm(0.01, "a test loop")
started = time.monotonic()
print("fed", flush=True)
while time.monotonic() - started < float(sys.argv[2]):
    if stall_after_s < 0 or time.monotonic() - started < stall_after_s:
        dog.feed(200)
    time.sleep(0.01)
stalled_s = dog.last_trip and dog.last_trip["stalled_s"]
print(json.dumps({"trips": trips, "idle": Daq.idle, "pauses": dog.pauses, "stalled_s": stalled_s}), flush=True)
dog.close()
"""


def _child(stall_after_s: float, run_s: float) -> subprocess.Popen:
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(stall_after_s), str(run_s)], cwd=ROOT, stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline().strip() == "fed"
    return proc


def test_a_process_stopped_for_1_s_resumes_without_a_trip():
    proc = _child(-1.0, 2.0)
    try:
        time.sleep(0.2)
        os.kill(proc.pid, signal.SIGSTOP)
        time.sleep(1.0)  # 3× the watchdog's timeout
        os.kill(proc.pid, signal.SIGCONT)
        out = json.loads(proc.communicate(timeout=30)[0])
    finally:
        proc.kill()
    assert out["trips"] == [] and out["idle"] == 0 and out["pauses"] >= 1, out


def test_a_loop_that_stalls_by_itself_still_trips():
    proc = _child(0.3, 1.5)
    try:
        out = json.loads(proc.communicate(timeout=30)[0])
    finally:
        proc.kill()
    assert out["idle"] == 1 and len(out["trips"]) == 1, out
    assert 0.3 <= out["stalled_s"] < 0.3 + 1.0, out  # its timeout, and a loaded machine's lateness
