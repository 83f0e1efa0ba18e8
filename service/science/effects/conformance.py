"""Conformance checks of the effect contract (service.science.effects.base), in the spirit of
scikit-learn's ``check_estimator``: each check runs the effect on a small synthetic two-axis record
(10 and 50 Hz blocks, the other axis driven alone, a temperature that rises 2 K) and reports what
fails by the check's name. Anything the effect raises is caught and reported, never propagated.

``evcbench effects check FILE`` prints them; the registry refuses a plug-in with any failure.
"""

from __future__ import annotations

import re
import traceback
from dataclasses import dataclass

import numpy as np

from service.science.data.record import Record
from service.science.data.signals import drive_derivatives
from service.science.effects.base import INVERSE_KINDS, Effect, RecordContext
from service.science.fitting.lsq import Block
from service.science.models.base import equal_thresholds
from service.science.models.kernels import play_operators

#: the stages a plug-in may use (``output`` is the gauge's, one per model: built-in only)
PLUGIN_STAGES = ("additive", "transform", "capacity")
#: a transform's steady-state output must match its frequency response within this share of |H|
RESPONSE_TOLERANCE = 0.05
NAME = re.compile(r"^[a-z][a-z0-9_]{1,39}$")
FS_HZ = 5000.0


@dataclass(frozen=True)
class Failure:
    """One failed check: its name and what was wrong, in words."""

    check: str
    message: str

    def __str__(self) -> str:
        return f"{self.check}: {self.message}"


def synthetic_record() -> Record:
    """10 Hz then 50 Hz biased sines on this axis (0.5 and 0.2 s), then a 20 Hz sine of the other
    axis alone (0.3 s; V); x = 0.1 µm/V·u; the temperature rises 2 K over the record."""
    t1, t5, tz = (np.arange(int(FS_HZ * d)) / FS_HZ for d in (0.5, 0.2, 0.3))
    u_y = np.concatenate([50 - 50 * np.cos(2 * np.pi * 10 * t1), 50 - 50 * np.cos(2 * np.pi * 50 * t5), 0 * tz])
    u_z = np.concatenate([0 * t1, 0 * t5, 40 - 40 * np.cos(2 * np.pi * 20 * tz)])
    edges = np.cumsum([0, t1.size, t5.size, tz.size])
    blocks = [
        {"start": int(a), "stop": int(b), "axis": ax, "frequency_hz": f}
        for a, b, ax, f in zip(edges[:-1], edges[1:], ("y", "y", "z"), (10.0, 50.0, 20.0))
    ]
    temp = 25.0 + 2.0 * np.arange(u_y.size) / u_y.size
    return Record(
        u_y, 0.1 * u_y, FS_HZ, blocks=blocks, axis="y", u_other_v=u_z, x_other_um=0.1 * u_z, temp_c=temp, hold_out=True
    )


def synthetic_context(record: Record, full: bool = True, n_operators: int = 10) -> RecordContext:
    """What an effect sees of ``record`` (``full``: with the other axis and the temperature; else as a
    feedforward inverse sees a planned drive: neither)."""
    thresholds = equal_thresholds(float(np.max(record.u_v)), n_operators)
    du, ddu = drive_derivatives(record.u_v, record.sample_rate_hz)
    other = record.u_other_v if full else None
    return RecordContext(
        record.u_v,
        record.sample_rate_hz,
        play_operators(record.u_v, thresholds),
        du,
        ddu,
        other,
        None if other is None else play_operators(other, thresholds),
        0.02,
        50.0,
        float(np.max(np.abs(record.u_v))),
        record.n_samples / record.sample_rate_hz,
        record.x_other_um if full else None,
        record.temp_c - record.temp_c.mean() if full else None,
    )


def _unit(effect: Effect, key: str, what: str, failures: list[Failure]) -> None:
    unit = (effect.units or {}).get(key)
    if not isinstance(unit, str) or not unit.strip():
        failures.append(Failure("units", f"{what} {key!r} has no unit in ``units`` (e.g. units = {{{key!r}: 'µm'}})"))


def _declaration(effect: Effect, builtin: bool) -> list[Failure]:
    out = []
    name = getattr(effect, "name", "")
    if not isinstance(name, str) or not NAME.match(name) or name == "hysteresis":
        out.append(Failure("name", f"{name!r} must be 2–40 lower-case letters, digits or _, not 'hysteresis'"))
    if effect.kind not in ("physical", "capacity"):
        out.append(Failure("kind", f"{effect.kind!r} is not 'physical' or 'capacity'"))
    stages = PLUGIN_STAGES + (("output", "drive") if builtin else ())
    if effect.stage not in stages:
        out.append(Failure("stage", f"{effect.stage!r} is not one of {', '.join(stages)}"))
    for attr in ("signature", "rule"):
        if not isinstance(getattr(effect, attr), str) or not getattr(effect, attr).strip():
            out.append(Failure(attr, f"``{attr}`` must say in words what it is"))
    if effect.inverse not in INVERSE_KINDS:
        out.append(Failure("inverse", f"{effect.inverse!r} is not one of {', '.join(INVERSE_KINDS)}"))
    elif effect.inverse == "none" and not effect.no_inverse.strip():
        out.append(Failure("inverse", "inverse = 'none' needs ``no_inverse``: why there is none, in words"))
    elif effect.stage == "transform" and effect.inverse not in ("response", "none"):
        out.append(Failure("inverse", "a transform's inverse is 'response' (with ``response``) or 'none'"))
    if not isinstance(effect.sweep, dict) or "waveform" not in effect.sweep:
        out.append(Failure("sweep", "``sweep`` must be an /api/sweeps body with a 'waveform'"))
    for where, body in [("sweep", effect.sweep)] + [
        (f"separated_from[{other!r}]", sep[1]) for other, sep in (effect.separated_from or {}).items()
    ]:
        out += _step_levels_failures(where, body)
    if effect.emulator_bench is not None and not (isinstance(effect.emulator_bench, str) and effect.emulator_bench):
        out.append(Failure("emulator_bench", "must be None or a bench config's name"))
    return out


def _step_levels_failures(where: str, body) -> list[Failure]:
    """A step body names its levels as shares of the drive range (``level_shares``, 0…1), not volts:
    the effect does not know the stage's range."""
    if not isinstance(body, dict) or body.get("waveform") != "step":
        return []
    shares = body.get("level_shares")
    if "levels_v" in body or not shares or not all(isinstance(x, int | float) and 0 <= x <= 1 for x in shares):
        return [
            Failure(
                where, "a step body gives its levels as ``level_shares`` (0…1 of the drive range), not ``levels_v``"
            )
        ]
    return []


def _blocks(effect: Effect, ctx: RecordContext, where: str) -> tuple[list[Block], list[Failure]]:
    """The effect's blocks on ``ctx`` and what is wrong with them."""
    try:
        blocks = effect.blocks(ctx)
    except Exception as exc:  # a plug-in's own error, reported by name
        return [], [Failure("blocks", f"raised {_error(exc)} ({where})")]
    if not isinstance(blocks, list) or not all(isinstance(b, Block) for b in blocks):
        return [], [Failure("blocks", f"must return a list of fitting.lsq.Block ({where})")]
    out = []
    for b in blocks:
        cols = b.columns
        if cols.ndim != 2 or cols.shape[0] != ctx.n:
            out.append(Failure("shapes", f"block {b.name!r} has shape {cols.shape}, not ({ctx.n}, k) ({where})"))
        elif not np.all(np.isfinite(cols)):
            out.append(Failure("finite", f"block {b.name!r} has non-finite values ({where})"))
        _unit(effect, b.name, "block", out)
    return blocks, out


def _transform(effect: Effect, record: Record) -> tuple[list[Failure], dict]:
    """The transform's failures and the grid's middle parameters (checked with them)."""
    out: list[Failure] = []
    try:
        grid = effect.grid(record.sample_rate_hz, 0.02, 50.0)
        theta = dict(grid[len(grid) // 2])
    except Exception as exc:
        return [Failure("grid", f"raised {_error(exc)}")], {}
    return out + _transformed(effect, record, theta), theta


def _drive(effect: Effect, record: Record) -> tuple[list[Failure], dict]:
    """A drive stage's failures (units, shape, finite) at its grid's middle parameters."""
    try:
        grid = effect.grid(record.sample_rate_hz, 0.02, 50.0)
        theta = dict(grid[len(grid) // 2])
        moved = np.asarray(effect.drive(record.u_v, record.sample_rate_hz, theta))
    except Exception as exc:
        return [Failure("drive", f"raised {_error(exc)}")], {}
    out: list[Failure] = []
    for key in theta:
        _unit(effect, key, "drive parameter", out)
    if moved.shape != record.u_v.shape or not np.all(np.isfinite(moved)):
        out.append(Failure("drive", f"returned shape {moved.shape} for {record.u_v.shape}, or non-finite values"))
    return out, theta


def _transformed(effect: Effect, record: Record, theta: dict) -> list[Failure]:
    out: list[Failure] = []
    for key in theta:
        _unit(effect, key, "transform parameter", out)
    cols = np.column_stack([record.u_v, np.ones(record.n_samples)])
    try:
        moved = np.asarray(effect.apply(cols, record.sample_rate_hz, theta))
    except Exception as exc:
        return out + [Failure("apply", f"raised {_error(exc)}")]
    if moved.shape != cols.shape or not np.all(np.isfinite(moved)):
        return out + [
            Failure("apply", f"returned shape {moved.shape} (finite: {np.all(np.isfinite(moved))}) for {cols.shape}")
        ]
    if effect.inverse == "response":
        out += _response_consistency(effect, theta)
    return out


def _response_consistency(effect: Effect, theta: dict) -> list[Failure]:
    """The transform's steady state on a 20 Hz cosine against its ``response`` there."""
    f, t = 20.0, np.arange(int(2 * FS_HZ)) / FS_HZ
    x = np.cos(2 * np.pi * f * t)
    try:
        y = np.asarray(effect.apply(x[:, None], FS_HZ, theta))[:, 0]
        h = complex(np.asarray(effect.response(np.array([f]), FS_HZ, theta)).ravel()[0])
    except Exception as exc:
        return [Failure("inverse", f"apply or response raised {_error(exc)}")]
    tail = slice(t.size // 2, None)
    basis = np.column_stack([np.cos(2 * np.pi * f * t[tail]), np.sin(2 * np.pi * f * t[tail])])
    (a, b), *_ = np.linalg.lstsq(basis, y[tail], rcond=None)
    measured = complex(a, -b)
    if not np.isfinite(h) or abs(measured - h) > RESPONSE_TOLERANCE * max(abs(h), 1e-3):
        return [Failure("inverse", f"response {h:.4g} at {f:g} Hz, but the transform's steady state is {measured:.4g}")]
    return []


def _words_and_rules(effect: Effect, record: Record) -> list[Failure]:
    out = []
    for check, call in (
        ("untestable", lambda: effect.untestable([record])),
        ("evidence", lambda: effect.evidence({}, {"noise_floor_um": 0.002, "repeatable_rms_um": 0.01})),
    ):
        try:
            value = call()
        except Exception as exc:
            out.append(Failure(check, f"raised {_error(exc)}"))
            continue
        if value is not None and not isinstance(value, str):
            out.append(Failure(check, f"must return words (str{' or None' if check == 'untestable' else ''})"))
    return out


def _parameters(effect: Effect, blocks: list[Block], theta: dict) -> list[Failure]:
    values = {b.name: np.full(b.columns.shape[1], 0.01) for b in blocks}
    scales = {"u_scale_v": 100.0, "min_period_s": 0.02, "time_scale_s": 1.2, "stroke_um": 10.0}
    out = []
    try:
        params = effect.parameters(theta, values, scales, 1.0)
        words = effect.describe(theta, values)
    except Exception as exc:
        return [Failure("parameters", f"parameters or describe raised {_error(exc)}")]
    for key, value in (params or {}).items():
        _unit(effect, key, "parameter", out)
        if not np.isfinite(value):
            out.append(Failure("parameters", f"{key!r} is not finite"))
    if not isinstance(words, str):
        out.append(Failure("describe", "must return words (str)"))
    return out


def check_effect(effect: Effect, builtin: bool = False) -> list[Failure]:
    """Every failed check of ``effect`` (empty: it conforms). ``builtin`` allows the gauge's stage."""
    if not isinstance(effect, Effect):
        return [Failure("contract", f"{type(effect).__name__} is not a subclass of service.science.effects.Effect")]
    failures = _declaration(effect, builtin)
    if failures:
        return failures
    record = synthetic_record()
    blocks, found = _blocks(effect, synthetic_context(record, full=True), "with the other axis and temp_c")
    failures += found
    failures += _blocks(effect, synthetic_context(record, full=False), "a planned drive alone, as an inverse sees it")[
        1
    ]
    if effect.stage in ("additive", "capacity") and not found and not any(np.any(b.columns) for b in blocks):
        failures.append(Failure("blocks", "every column is zero on a record with every input: nothing to fit"))
    theta = {}
    if effect.stage == "transform":
        found, theta = _transform(effect, record)
        failures += found
    elif effect.stage == "drive":
        found, theta = _drive(effect, record)
        failures += found
    failures += _words_and_rules(effect, record)
    failures += _parameters(effect, blocks, theta)
    return failures


def _error(exc: BaseException) -> str:
    """``Type: message`` and where in the plug-in it was raised."""
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" at {frames[-1].filename.rsplit('/', 1)[-1]}:{frames[-1].lineno}" if frames else ""
    return f"{type(exc).__name__}: {exc}{where}"
