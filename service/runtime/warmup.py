"""Fill numba's on-disk cache with the product's compiled kernels before anything needs them.

On a fresh install the cache is empty: opening an emulated bench compiles its per-sample world (into
the buffered loop, and into the tracking loop's runner that the bench engine compiles as it
starts), so the first `evcbench serve` answered /api/health after 19.3 s instead of 2.4 s, and the
first fit took 2.4 s instead of 1.3 s (a static PI on a 4-frequency sweep, over REST). Every process that
starts before the cache holds a kernel compiles it again: on an empty cache the test suite's two
workers compiled the same kernels side by side, 22 s each (44.5 s of CPU by numba's compile
events, one run), while the set-up before them had a core to spare.

``warm(parts)`` runs each kernel of a part once through the product's own paths (an emulated sweep;
the paper's models and a composite with the effects that have kernels fitted, predicted and
inverted on a synthetic record; the tracking loop's runner, error watch and learning kernels and
the bench's one-sample step) with the argument types the product passes, so that later processes
load machine code from the cache (drivers/jit.py keeps a cache that several processes fill
consistent). ``make test`` runs "emulator loop" beside "models" while it installs the rest: the loop
part after the emulator's in one process, because opening a bench compiles (or loads) its world
(``World._compile``), which a second process would compile again at the same time. The command
is ``evcbench warm``.
"""

from __future__ import annotations

import time

import numpy as np

#: the emulated bench the emulator's part sweeps: one frequency, a few cycles (a second of emulation)
WARM_BENCH = "default"
WARM_FREQUENCIES_HZ = (10.0,)
WARM_CYCLES = 3
#: the models' part fits a record of its own (no emulator): the paper's 0–120 V drive at 10 Hz,
#: 4 cycles at the DAQ's 20 kHz, through a first-order lag (1 ms, which opens a loop) and a quadratic gain
RECORD_RATE_HZ = 20_000.0
RECORD_FREQUENCY_HZ = 10.0
RECORD_CYCLES = 4
RECORD_LAG_S = 1e-3


def _emulator() -> None:
    """The buffered and idle loops (a sweep) with every hysteresis family's update."""
    from drivers.factory import open_bench
    from service.science.data.plans import SinePlan
    from service.science.discovery.records import run_records

    sweep = SinePlan(axes=("y", "z"), frequencies_hz=WARM_FREQUENCIES_HZ, cycles=WARM_CYCLES, together=False)
    run_records(open_bench(WARM_BENCH, 0), sweep, WARM_BENCH + ":")


def _loop() -> None:
    """The point-by-point paths: the tracking loop's runner (the bench engine compiles it as it
    starts), its error watch, the learning kernels and the bench's one-sample step."""
    from drivers.factory import open_bench
    from service.science.control import ilc
    from service.science.control import kernels as control_kernels
    from service.science.control.loop import compile_runner

    bench = open_bench(WARM_BENCH, 0)
    try:
        compile_runner(bench)
        bench.step({axis: 0.0 for axis in bench.axes})
    finally:
        bench.close()
    empty = np.zeros((0, 2))
    control_kernels.watch_block(empty, empty.copy(), np.zeros((2, control_kernels.NT)), np.zeros(2))
    ilc.compile_kernels()


def _models() -> None:
    """The paper's models fitted, predicted and inverted, a composite with the effects whose
    columns are compiled (Duhem operators, the flexure's resonance) fitted and inverted, and one with
    the other compiled columns and drive stage (hysterons, the rate limit) fitted and predicted."""
    from service.science.data.record import Record
    from service.science.data.signals import biased_sine
    from service.science.discovery.composite import CompositeModel
    from service.science.effects.creep import first_order_lowpass
    from service.science.models import PAPER_MODELS

    drive = biased_sine(RECORD_FREQUENCY_HZ, RECORD_CYCLES, RECORD_RATE_HZ)
    lagged_v = first_order_lowpass(drive.value, RECORD_LAG_S, RECORD_RATE_HZ)
    n = drive.value.size
    record = Record(
        drive.value,
        0.1 * lagged_v + 2e-4 * lagged_v**2,
        RECORD_RATE_HZ,
        du_v_per_s=drive.d1_per_s,
        ddu_v_per_s2=drive.d2_per_s2,
        label="warm-up",
        axis="y",
        blocks=[
            {
                "index": 0,
                "start": 0,
                "stop": n,
                "kind": "sine",
                "frequency_hz": RECORD_FREQUENCY_HZ,
                "cycles": RECORD_CYCLES,
                "axes": ["y"],
            }
        ],
    )
    x_ref = record.require_x()
    models = [cls().fit([record]) for cls in PAPER_MODELS.values()]
    models.append(CompositeModel(["operators", "dynamics"]).fit([record]))
    for model in models:
        model.predict(record)
        model.inverse(x_ref, sample_rate_hz=record.sample_rate_hz)
    # the wider base's hysterons and the amplifier's rate limit (a drive stage, no inverse): every
    # diagnosis tries them, so each test worker compiled them (4.8 s of CPU) when it was not done here
    CompositeModel(["hysterons", "slew_limit"]).fit([record]).predict(record)


#: part -> what it compiles (run by ``warm``)
PARTS = {"emulator": _emulator, "models": _models, "loop": _loop}


def warm(parts=None) -> dict[str, float]:
    """Run the named ``parts`` of PARTS (None: all); {part: seconds it took}. ValueError naming an
    unknown part before any runs."""
    parts = tuple(PARTS) if parts is None else tuple(parts)
    unknown = [p for p in parts if p not in PARTS]
    if unknown:
        raise ValueError(f"part: unknown {', '.join(map(repr, unknown))}; known: {', '.join(PARTS)}")
    took = {}
    for part in parts:
        start = time.perf_counter()
        PARTS[part]()
        took[part] = round(time.perf_counter() - start, 2)
    return took
