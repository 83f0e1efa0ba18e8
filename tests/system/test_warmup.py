"""`evcbench warm` (service.runtime.warmup) fills numba's on-disk cache, so that a later process
running the product's paths on other benches, other records and other models compiles none of the
product's kernels: it loads them all.

Both processes use the suite's shared cache (a private empty one would make this test compile
every kernel: half a minute of a worker). `make test` fills it with the same command before the
workers start, and this test runs first on its worker (mark ``first``, tests/conftest.py), before
other tests add kernels to the cache: a kernel or argument type the product's paths reach and the
warm-up misses is compiled by the probe, and fails the test. (The other worker starts at the same
moment; a kernel it compiles in the probe's first seconds could still hide a miss.)"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.first]

#: a process that lists the product kernels numba compiles (its "numba:compile" event fires on a
#: cache miss only) while it sweeps two emulated benches of other hysteresis families and seeds,
#: fits, predicts and inverts every paper model and a composite on that data, and compiles the
#: tracking loop of a third bench
PROBE = r"""
import json
from numba.core import event

compiled = []

class Listener(event.Listener):
    def on_start(self, ev):
        f = ev.data["dispatcher"].py_func
        if f.__module__.split(".")[0] in ("drivers", "service"):
            compiled.append(f"{f.__module__}.{f.__qualname__}")

    def on_end(self, ev):
        pass

event.register("numba:compile", Listener())

from drivers.factory import open_bench
from service.science.control.loop import compile_runner
from service.science.discovery.composite import CompositeModel
from service.lab.emulated import sweep_records
from service.science.models import PAPER_MODELS

records = sweep_records("bw_creep", 3, frequencies_hz=(5.0, 50.0), cycles=2)
records.update({f"ms_{k}": r for k, r in sweep_records("ms_base", 1, frequencies_hz=(20.0,), cycles=2).items()})
y, z = records["y"], records["ms_z"]
for model in [cls().fit([y]) for cls in PAPER_MODELS.values()] + [CompositeModel(["dynamics", "operators"]).fit([z])]:
    model.predict(z)
    model.inverse(z.x_um, sample_rate_hz=z.sample_rate_hz)
bench = open_bench("dynamics", 2)
compile_runner(bench)
bench.step({"y": 1.0, "z": 0.0})
bench.close()
print(json.dumps(compiled))
"""


def _run(args: list[str], env: dict) -> subprocess.CompletedProcess:
    return subprocess.run(args, env=env, capture_output=True, text=True, timeout=600)


def test_after_warm_a_new_process_compiles_none_of_the_products_kernels():
    env = dict(os.environ)
    warmed = _run([sys.executable, "-m", "service.frontends.cli", "warm", "--json"], env)
    assert warmed.returncode == 0, warmed.stderr
    took = json.loads(warmed.stdout)
    assert set(took) == {"emulator", "models", "loop"} and all(s >= 0 for s in took.values())

    probe = _run([sys.executable, "-c", PROBE], env)
    assert probe.returncode == 0, probe.stderr
    assert json.loads(probe.stdout.splitlines()[-1]) == []


def test_an_unknown_part_is_refused_naming_it():
    done = _run([sys.executable, "-m", "service.frontends.cli", "warm", "emulator", "compiler"], dict(os.environ))
    assert done.returncode == 2
    assert "part: unknown 'compiler'" in done.stderr and "emulator, models, loop" in done.stderr
