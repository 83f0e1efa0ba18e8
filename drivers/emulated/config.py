"""Bench configurations: TOML files in fixtures/benches/, ``extends``, overrides, validation.

A file may say ``extends = "base"`` and give only what differs; ``extends = ["creep", "bw_base"]``
stands on several parents (a hidden effect on another hysteresis family: see ``_chain``). Overrides are a nested dict or
dotted keys (``{"daq.latency.samples": 3}``); ``axes.*.…`` applies to both axes. Every leaf is
checked against ``RULES``; a bad or unknown key raises ValueError naming it.
"""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parents[2] / "fixtures" / "benches"
AXES = ("y", "z")

EFFECTS = (
    "daq.quantisation",
    "daq.latency",
    "ambient.drift",
    "coupling",
    "axes.*.amplifier.bandwidth",
    "axes.*.amplifier.noise",
    "axes.*.piezo.hysteresis",
    "axes.*.piezo.rate_dependence",
    "axes.*.piezo.creep",
    "axes.*.piezo.asymmetry",
    "axes.*.piezo.temperature",
    "axes.*.piezo.depolarisation",
    "axes.*.flexure.dynamics",
    "axes.*.gauge.bandwidth",
    "axes.*.gauge.noise",
    "axes.*.gauge.nonlinearity",
    "axes.*.gauge.drift",
    "axes.*.gauge.pickup",
)

# leaf path -> ("num" | "int", min, max) | ("bool",) | ("str", allowed values or None)
RULES: dict[str, tuple] = {
    "name": ("str", None),
    "description": ("str", None),
    "seed": ("int", 0, 2**63 - 1),
    "daq.timebase_hz": ("num", 1e6, 1e10),
    "daq.sample_rate_hz": ("num", 1.0, 1e8),
    "daq.max_sample_rate_hz": ("num", 1.0, 1e8),
    "daq.range_v": ("num", 0.1, 100.0),
    "daq.resolution_bits": ("int", 8, 24),
    "daq.monitor_ratio_v_per_v": ("num", 1e-4, 1.0),
    "daq.latency.samples": ("int", 0, 1000),
    "daq.realtime": ("bool",),
    "ambient.temperature_c": ("num", -40.0, 100.0),
    "ambient.thermometer": ("bool",),
    "ambient.drift.rate_c_per_s": ("num", -1.0, 1.0),
    "ambient.drift.cycle_amplitude_c": ("num", 0.0, 20.0),
    "ambient.drift.cycle_period_s": ("num", 1.0, 1e7),
    "coupling.y_from_z": ("num", -0.5, 0.5),
    "coupling.z_from_y": ("num", -0.5, 0.5),
    "axes.*.amplifier.gain_v_per_v": ("num", 0.1, 1000.0),
    "axes.*.amplifier.output_min_v": ("num", -1000.0, 0.0),
    "axes.*.amplifier.output_max_v": ("num", 1.0, 1000.0),
    "axes.*.amplifier.slew_limit_v_per_s": ("num", 1.0, 1e9),
    "axes.*.amplifier.current_limit_a": ("num", 1e-6, 100.0),
    "axes.*.amplifier.load_capacitance_f": ("num", 1e-12, 1.0),
    "axes.*.amplifier.large_signal_capacitance_factor": ("num", 1.0, 5.0),
    "axes.*.amplifier.overcurrent_fault_s": ("num", 1e-5, 10.0),
    "axes.*.amplifier.overcurrent_reset_s": ("num", 1e-5, 10.0),
    "axes.*.amplifier.bandwidth.bandwidth_hz": ("num", 1.0, 1e8),
    "axes.*.amplifier.noise.rms_v": ("num", 0.0, 10.0),
    "axes.*.piezo.rated_min_v": ("num", -1000.0, 0.0),
    "axes.*.piezo.rated_max_v": ("num", 1.0, 1000.0),
    "axes.*.piezo.reversible_um_per_v": ("num", 0.0, 10.0),
    "axes.*.piezo.hysteresis.switched_um": ("num", 0.0, 1000.0),
    "axes.*.piezo.hysteresis.reference_v": ("num", 1.0, 1000.0),
    "axes.*.piezo.hysteresis.coercive_mode_v": ("num", 0.05, 1000.0),
    "axes.*.piezo.hysteresis.bias_center_v": ("num", -1000.0, 1000.0),
    "axes.*.piezo.hysteresis.bias_width_v": ("num", 0.5, 1e5),
    "axes.*.piezo.hysteresis.initial_state": ("str", ("virgin", "descended")),
    "axes.*.piezo.hysteresis.family": ("str", ("preisach", "bouc_wen", "maxwell_slip")),
    "axes.*.piezo.hysteresis.bouc_wen.hysteretic_gain": ("num", 0.01, 0.99),
    "axes.*.piezo.hysteresis.bouc_wen.lag_saturation_v": ("num", 0.1, 200.0),
    "axes.*.piezo.hysteresis.bouc_wen.gamma_over_beta": ("num", -0.9, 1.0),
    "axes.*.piezo.hysteresis.bouc_wen.exponent": ("num", 1.0, 10.0),
    "axes.*.piezo.hysteresis.bouc_wen.max_step_v": ("num", 0.001, 10.0),
    "axes.*.piezo.hysteresis.maxwell_slip.elements": ("int", 2, 256),
    "axes.*.piezo.hysteresis.maxwell_slip.threshold_median_v": ("num", 0.2, 80.0),
    "axes.*.piezo.hysteresis.maxwell_slip.threshold_log_sigma": ("num", 0.0, 3.0),
    "axes.*.piezo.hysteresis.maxwell_slip.slip_fraction": ("num", 0.01, 0.99),
    "axes.*.piezo.hysteresis.maxwell_slip.elastic_fraction": ("num", 0.0, 0.9),
    "axes.*.piezo.hysteresis.maxwell_slip.distribution_seed": ("int", 0, 2**32 - 1),
    "axes.*.piezo.rate_dependence.relaxation_s": ("num", 0.0, 10.0),
    "axes.*.piezo.rate_dependence.relaxing_fraction": ("num", 0.0, 1.0),
    "axes.*.piezo.creep.rate_per_decade": ("num", 0.0, 0.5),
    "axes.*.piezo.creep.tau_min_s": ("num", 1e-5, 1e7),
    "axes.*.piezo.creep.tau_max_s": ("num", 1e-5, 1e7),
    "axes.*.piezo.creep.modes_per_decade": ("int", 1, 20),
    "axes.*.piezo.asymmetry.electrostrictive_um_per_v2": ("num", -1.0, 1.0),
    "axes.*.piezo.asymmetry.saturation_um": ("num", 0.01, 1e4),
    "axes.*.piezo.temperature.gain_per_c": ("num", -0.1, 0.1),
    "axes.*.piezo.temperature.reference_c": ("num", -40.0, 100.0),
    "axes.*.piezo.depolarisation.loss_fraction": ("num", 0.0, 0.9),
    "axes.*.piezo.depolarisation.time_constant_s": ("num", 1.0, 1e9),
    "axes.*.flexure.resonance_hz": ("num", 1.0, 1e6),
    "axes.*.flexure.dynamics.damping_ratio": ("num", 1e-3, 5.0),
    "axes.*.gauge.scale_um_per_v": ("num", 1e-3, 1e3),
    "axes.*.gauge.offset_um": ("num", -1e3, 1e3),
    "axes.*.gauge.bandwidth.bandwidth_hz": ("num", 1.0, 1e8),
    "axes.*.gauge.noise.rms_nm": ("num", 0.0, 1e4),
    "axes.*.gauge.nonlinearity.fraction_of_range": ("num", 0.0, 0.1),
    "axes.*.gauge.drift.offset_rate_nm_per_s": ("num", -1e5, 1e5),
    "axes.*.gauge.pickup.frequency_hz": ("num", 1.0, 1e5),
    "axes.*.gauge.pickup.amplitude_nm": ("num", 0.0, 1e5),
    "axes.*.gauge.pickup.third_harmonic_nm": ("num", 0.0, 1e5),
}
for _effect in EFFECTS:
    RULES[_effect + ".enabled"] = ("bool",)
    RULES[_effect + ".scale"] = ("num", 0.0, 1000.0)
FAMILY_KEY = "axes.*.piezo.hysteresis.family"
#: the family's own table: required when the family is selected, ignored otherwise
FAMILY_TABLES = {family: f"axes.*.piezo.hysteresis.{family}." for family in ("bouc_wen", "maxwell_slip")}
OPTIONAL = {
    "seed",
    "description",
    "daq.realtime",
    "ambient.thermometer",
    FAMILY_KEY,
    "axes.*.piezo.rate_dependence.relaxing_fraction",
    "axes.*.amplifier.large_signal_capacitance_factor",
    *(k for k in RULES if any(k.startswith(prefix) for prefix in FAMILY_TABLES.values())),
}
CHECKED_ELSEWHERE = ("transport", "safety", "faults", "emulator")


def list_benches() -> list[str]:
    """Names of the bench configurations in fixtures/benches/."""
    return sorted(p.stem for p in BENCH_DIR.glob("*.toml"))


def _resolve(name_or_path: str | Path, base_dir: Path = BENCH_DIR) -> Path:
    text = str(name_or_path)
    if text.endswith(".toml") or "/" in text or "\\" in text:
        path = Path(text)
        if not path.is_absolute() and not path.exists():
            path = base_dir / path
    else:
        path = base_dir / f"{text}.toml"
    if not path.is_file():
        raise ValueError(f"bench {text!r}: no such configuration (known: {', '.join(list_benches())})")
    return path


def deep_merge(base: dict, over: dict) -> dict:
    """A copy of ``base`` with ``over`` merged in (tables merge, values replace)."""
    out = copy.deepcopy(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _chain(path: Path, seen: tuple[Path, ...] = ()) -> list[tuple[Path, dict]]:
    """The files ``path`` stands on, ancestors first, each once (its own values, ``extends`` removed).
    Parents listed together are linearised left to right and an ancestor they share is applied
    once, first: ``["creep", "bw_base"]`` is default, base, creep, bw_base."""
    if path in seen:
        raise ValueError(f"extends: cycle through {' -> '.join(p.stem for p in seen + (path,))}")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path.name}: not valid TOML ({exc})") from None
    data.setdefault("name", path.stem)
    parents = data.pop("extends", None)
    if parents is None:
        return [(path, data)]
    if isinstance(parents, str):
        parents = [parents]
    if not isinstance(parents, list) or not parents or not all(isinstance(p, str) for p in parents):
        raise ValueError(f"extends: must be a bench name or path, or a list of them, got {parents!r}")
    chain: list[tuple[Path, dict]] = []
    for parent in parents:
        for item in _chain(_resolve(parent, path.parent), seen + (path,)):
            if all(item[0] != done for done, _ in chain):
                chain.append(item)
    return chain + [(path, data)]


def _load_file(path: Path) -> dict:
    merged: dict = {}
    for _, data in _chain(path):
        merged = deep_merge(merged, data)
    return merged


def _expand_overrides(overrides: dict) -> dict:
    """Dotted keys -> nested dicts; 'axes.*.x' -> both axes."""
    nested: dict = {}
    for key, value in overrides.items():
        if isinstance(value, dict) and "." not in key:
            value = _expand_overrides(value)
            if key == "*":
                for ax in AXES:
                    nested = deep_merge(nested, {ax: value})
            else:
                nested = deep_merge(nested, {key: value})
            continue
        parts = key.split(".")
        if "*" in parts:
            i = parts.index("*")
            for ax in AXES:
                nested = deep_merge(nested, _expand_overrides({".".join(parts[:i] + [ax] + parts[i + 1 :]): value}))
            continue
        node: dict = {}
        cur = node
        for part in parts[:-1]:
            cur[part] = {}
            cur = cur[part]
        cur[parts[-1]] = _expand_overrides(value) if isinstance(value, dict) else value
        nested = deep_merge(nested, node)
    return nested


def _leaves(tree: dict, prefix: str = ""):
    for key, value in tree.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            yield from _leaves(value, path + ".")
        else:
            yield path, value


def _rule_for(path: str) -> tuple | None:
    parts = path.split(".")
    if len(parts) > 2 and parts[0] == "axes" and parts[1] in AXES:
        parts[1] = "*"
    return RULES.get(".".join(parts))


def validate(cfg: dict) -> dict:
    """Check every leaf against RULES, that nothing is missing and cross-field constraints."""
    if set(cfg.get("axes", {})) != set(AXES):
        raise ValueError(f"axes: need exactly {', '.join(AXES)}, got {sorted(cfg.get('axes', {}))}")
    present = set()
    # optional tables checked elsewhere: [transport] by drivers.composed, [safety] by drivers.watchdog,
    # [faults] by drivers.emulated.faults, [emulator] by drivers.emulated.output_log
    for path, value in _leaves({k: v for k, v in cfg.items() if k not in CHECKED_ELSEWHERE}):
        rule = _rule_for(path)
        if rule is None:
            raise ValueError(f"{path}: unknown key")
        kind = rule[0]
        if kind == "bool":
            if not isinstance(value, bool):
                raise ValueError(f"{path}: must be true or false, got {value!r}")
        elif kind == "str":
            if not isinstance(value, str) or (rule[1] is not None and value not in rule[1]):
                allowed = f" (one of {', '.join(rule[1])})" if rule[1] else ""
                raise ValueError(f"{path}: must be a string{allowed}, got {value!r}")
        else:
            ok_type = isinstance(value, int) if kind == "int" else isinstance(value, (int, float))
            if isinstance(value, bool) or not ok_type:
                raise ValueError(f"{path}: must be {'an integer' if kind == 'int' else 'a number'}, got {value!r}")
            if not (rule[1] <= value <= rule[2]) or value != value:
                raise ValueError(f"{path}: {value!r} is outside {rule[1]:g}..{rule[2]:g}")
        present.add(path)
    for rule_path in RULES:
        if rule_path in OPTIONAL:
            continue
        paths = [rule_path.replace("*", ax) for ax in AXES] if "*" in rule_path else [rule_path]
        for p in paths:
            if p not in present:
                raise ValueError(f"{p}: missing")
    daq = cfg["daq"]
    if daq["sample_rate_hz"] > daq["max_sample_rate_hz"]:
        raise ValueError(f"daq.sample_rate_hz: {daq['sample_rate_hz']} exceeds daq.max_sample_rate_hz")
    for ax in AXES:
        c = cfg["axes"][ax]
        _check_family(ax, c["piezo"]["hysteresis"], present)
        if c["piezo"]["rated_min_v"] >= c["piezo"]["rated_max_v"]:
            raise ValueError(f"axes.{ax}.piezo.rated_min_v: must be below rated_max_v")
        if c["piezo"]["creep"]["tau_min_s"] >= c["piezo"]["creep"]["tau_max_s"]:
            raise ValueError(f"axes.{ax}.piezo.creep.tau_min_s: must be below tau_max_s")
        if c["amplifier"]["output_max_v"] * daq["monitor_ratio_v_per_v"] > daq["range_v"]:
            raise ValueError(f"daq.monitor_ratio_v_per_v: monitor of axis {ax} would exceed ±{daq['range_v']} V")
    return cfg


def _check_family(ax: str, hyst: dict, present: set) -> None:
    """The selected family's table is complete and its branches rise with the drive."""
    family = hyst.get("family", "preisach")
    prefix = FAMILY_TABLES.get(family)
    if prefix is None:
        return
    for rule_path in RULES:
        if rule_path.startswith(prefix) and rule_path.replace("*", ax) not in present:
            raise ValueError(f"{rule_path.replace('*', ax)}: missing (needed by family = {family!r})")
    if family == "bouc_wen":
        bw = hyst["bouc_wen"]
        if bw["hysteretic_gain"] > (1.0 + bw["gamma_over_beta"]) / 2.0:  # slope 1 − 2A/(1 + γ/β) after a reversal
            raise ValueError(
                f"axes.{ax}.piezo.hysteresis.bouc_wen.hysteretic_gain: {bw['hysteretic_gain']!r} exceeds "
                f"(1 + gamma_over_beta)/2 = {(1.0 + bw['gamma_over_beta']) / 2.0:g}: the strain would "
                "fall while the drive rises after a reversal"
            )


def load_config(name_or_path: str = "default", overrides: dict | None = None) -> dict:
    """Load fixtures/benches/<name>.toml (or a path), resolve ``extends``, merge overrides, validate."""
    from drivers.emulated.faults import check_config as check_faults
    from drivers.emulated.output_log import check_config as check_emulator
    from drivers.watchdog import SafetyConfig

    cfg = _load_file(_resolve(name_or_path))
    if overrides:
        if not isinstance(overrides, dict):
            raise ValueError(f"overrides: must be a dict, got {type(overrides).__name__}")
        cfg = deep_merge(cfg, _expand_overrides(overrides))
    SafetyConfig.from_config(cfg.get("safety"))
    check_faults(cfg.get("faults"))
    check_emulator(cfg.get("emulator"))
    return validate(cfg)
