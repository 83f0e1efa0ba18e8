"""High-fidelity emulated bench: the physics of the two-axis EVC device ("the world").

    from drivers.factory import open_bench
    bench = open_bench("default", seed=1)          # fixtures/benches/default.toml
    bench.parts.world.inject_fault("sensor_dropout", "y")          # now
    bench.parts.world.faults.add("loop_stall", after_s=0.4)        # scheduled (faults.py)
    bench.parts.world.output_log.last()                            # what the amplifiers got (output_log.py)

Configurations live in fixtures/benches/ (``list_benches()``); ``load_config`` resolves
``extends`` and overrides. Every effect is switchable and scalable there, and the hysteresis
family is chosen per axis (``[axes.<axis>.piezo.hysteresis] family``: preisach, the default,
bouc_wen or maxwell_slip; clean benches base, bw_base, ms_base and their hidden-effect variants).
"""

from __future__ import annotations

from drivers.bench import Bench
from drivers.emulated.config import list_benches, load_config
from drivers.emulated.devices import EmulatedAmplifier, EmulatedDaq, EmulatedSensor, build_devices
from drivers.emulated.world import FAULT_KINDS, World
from drivers.interfaces import BenchParts

__all__ = [
    "emulated_bench",
    "load_config",
    "list_benches",
    "World",
    "EmulatedDaq",
    "EmulatedAmplifier",
    "EmulatedSensor",
    "FAULT_KINDS",
]


def emulated_bench(cfg: dict, seed: int, safe_open=None) -> Bench:
    """The Bench of a loaded configuration ``cfg`` (``load_config``) without a ``[transport]`` table:
    the world and its devices in process, noise ``seed``; ``safe_open`` (drivers.safe_state.SafeOpen):
    0 V and the amplifiers disabled as they open, before the sensors."""
    world = World(cfg, seed)
    daq, amps, sensors = build_devices(world)
    if safe_open is not None:
        safe_open.daq_opened(daq)
        safe_open.amplifiers_opened(amps)
        safe_open.sensors_opened()
    parts = BenchParts(
        daq=daq,
        amplifiers=amps,
        sensors=sensors,
        resonance_hz={ax: world.resonance_hz(ax) for ax in ("y", "z")},
        backend=f"emulated:{cfg['name']}",
        config=cfg,
        world=world,
    )
    return Bench(parts)
