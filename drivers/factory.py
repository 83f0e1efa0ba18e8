"""The factory for a bench: a configuration (fixtures/benches/<name>.toml or a path, resolved by
drivers.emulated.config.load_config) opened as the emulated world in process, or part by part over
real transports when it has a ``[transport]`` table (drivers.composed: serial, CAN, NI-DAQmx).

    from drivers.factory import open_bench
    bench = open_bench("default", seed=1)
"""

from __future__ import annotations

from drivers.bench import Bench
from drivers.composed import open_from_config
from drivers.emulated import emulated_bench
from drivers.emulated.config import load_config
from drivers.safe_state import SafeOpen


def open_bench(
    name_or_path: str = "default",
    seed: int | None = None,
    overrides: dict | None = None,
    safe_open: SafeOpen | None = None,
) -> Bench:
    """Build the bench a configuration describes (``overrides``: dotted keys) and return it.

    ``seed`` None takes the file's ``seed`` (0 if absent). Same name, seed and overrides give
    bit-identical runs. ``safe_open`` (the bench engine's): the outputs are put at 0 V and the
    amplifiers disabled as each opens, before the sensors open (drivers.safe_state.SafeOpen)."""
    cfg = load_config(name_or_path, overrides)
    if seed is None:
        seed = int(cfg.get("seed", 0))
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed: must be a non-negative integer, got {seed!r}")
    cfg["seed"] = seed
    if "transport" in cfg:  # a per-part transport table: serial / CAN / NI-DAQmx parts (drivers.composed)
        return open_from_config(cfg, seed, safe_open)
    return emulated_bench(cfg, seed, safe_open)
