"""High-fidelity emulated bench: the physics of the two-axis EVC device ("the world").

    from drivers.emulated import open_bench
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
    "open_bench",
    "load_config",
    "list_benches",
    "World",
    "EmulatedDaq",
    "EmulatedAmplifier",
    "EmulatedSensor",
    "FAULT_KINDS",
]


def open_bench(name_or_path: str = "default", seed: int | None = None, overrides: dict | None = None) -> Bench:
    """Build the world and its devices from a bench configuration and return a Bench.

    ``seed`` None takes the file's ``seed`` (0 if absent). Same name, seed and overrides give
    bit-identical runs."""
    cfg = load_config(name_or_path, overrides)
    if seed is None:
        seed = int(cfg.get("seed", 0))
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed: must be a non-negative integer, got {seed!r}")
    cfg["seed"] = seed
    if "transport" in cfg:  # a per-part transport table: serial / CAN / NI-DAQmx parts (drivers.composed)
        from drivers.composed import open_from_config

        return open_from_config(cfg, seed)
    world = World(cfg, seed)
    daq, amps, sensors = build_devices(world)
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
