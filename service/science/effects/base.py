"""The effect contract: what every physical effect (and the capacity candidate) provides, built-in
or a plug-in (service.science.effects.registry loads both; docs/how-to/add-your-own-effect.md).

Everything about an effect lives on its class, so that no module outside the effect's own names it:
- its design: ``blocks`` (additive columns) or a transform (``grid``/``apply``), and ``units``, the
  unit of every weight block, transform parameter and reported parameter it names;
- its identifiability rule: ``rule`` in words, ``untestable(records)`` (the reason the data cannot
  test it, or None) and ``sweep``, the /api/sweeps body that would;
- its evidence in words: ``signature`` and ``evidence(sig, floor)``;
- its feedforward inverse: ``inverse`` ("iterate", "response", "invert" or "none" with ``no_inverse``);
- its emulator variant, as data: ``emulator_bench``, a bench config in fixtures/benches/;
- constants it learns from the records before any fit (``setup``: a disturbance's line frequencies),
  stored with the model and given back in ``RecordContext.learned``.

An effect acts on the composite model's design in one of five places (``stage``):
- ``drive``: a map of the drive before everything else (the amplifier's rate limit: ``drive``), its
  one parameter found by a 1-D search (``grid``, ``refine``) like a transform's;
- ``additive``: extra regressor columns (weights by least squares);
- ``transform``: a linear operator applied to every column (delay, flexure dynamics) whose few
  nonlinear parameters are found by a 1-D/2-D outer search;
- ``output``: a static map of the model's output (the gauge's own curvature, sensor_nonlinearity.py);
- ``capacity``: a change of the hysteresis basis itself (more play operators).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from service.science.effects.rules import RATE_SWEEP
from service.science.fitting.lsq import Block

#: how a feedforward inverse (service.science.discovery.composite_inverse) undoes an effect
INVERSE_KINDS = {
    "iterate": "its columns are functions of the planned drive: the inverse's iteration compensates them",
    "response": "a linear transform: divided out per harmonic by its frequency response (``response``)",
    "invert": "a static map of the output: undone by ``invert``",
    "none": "no inverse: a feedforward leaves it out (``no_inverse`` says why)",
}


@dataclass
class RecordContext:
    """One record as the effects see it (arrays at the full sample rate ``fs_hz``).

    ``p`` play-operator outputs (V), ``du``/``ddu`` drive derivatives (V/s, V/s²),
    ``u_other_v`` the other axis's drive (or None), ``min_period_s`` the shortest drive period
    over the data set, ``time_scale_s`` the longest record's duration over the data set (so that
    time-based columns mean the same seconds in every record, whatever its length), ``x_other_um``
    the other axis's measured displacement (µm; None when not measured, e.g. in a feedforward inverse),
    ``temp_dev_k`` the temperature less its mean over the data set (K; None without a thermometer).
    """

    u_v: np.ndarray
    fs_hz: float
    p: np.ndarray
    du: np.ndarray
    ddu: np.ndarray
    u_other_v: np.ndarray | None
    p_other: np.ndarray | None
    min_period_s: float
    max_frequency_hz: float
    u_scale_v: float
    time_scale_s: float
    x_other_um: np.ndarray | None = None
    #: the stack's temperature less the data set's mean (K), where the records carry temp_c
    temp_dev_k: np.ndarray | None = None
    cache: dict = field(default_factory=dict)
    #: what each effect's ``setup`` learned from the fitted records, by effect name
    learned: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return self.u_v.size

    @property
    def t_s(self) -> np.ndarray:
        return np.arange(self.n) / self.fs_hz


def sum_of_taps(taps, columns: np.ndarray) -> np.ndarray:
    """Σ weight·columns[input_rows] over a row-local transform's ``taps`` (``Effect.taps``)."""
    (w, rows), *rest = taps
    out = w * columns[rows]
    for w, rows in rest:
        out = out + w * columns[rows]
    return out


class Effect:
    """Base: subclasses set ``name``, ``kind``, ``stage``, ``signature`` and implement the hooks."""

    name: ClassVar[str] = ""
    kind: ClassVar[str] = "physical"  # or "capacity"
    stage: ClassVar[str] = "additive"
    #: the residual signature in words (what the diagnosis looks for)
    signature: ClassVar[str] = ""
    #: transforms: True if the transform commutes with time shifts of the drive (delay, LTI filters)
    shift_invariant: ClassVar[bool] = True
    #: a model with the effect draws a point-symmetric loop for a sine drive in the steady state, as a
    #: PI does (x(t + T/2) = 2x_c − x(t)): linear lags, modes, delays, creep; not a warped operator
    #: family, a parabola in the drive or segment-switched rate terms (service.science.discovery.symmetry)
    point_symmetric: ClassVar[bool] = True
    #: the unit of every weight block (``blocks``' names), transform parameter (``grid``'s keys) and
    #: reported parameter (``parameters``' keys) the effect names, e.g. {"drift_legendre_um": "µm"}
    units: ClassVar[dict[str, str]] = {}
    #: the identifiability rule in words: what the data must contain to test the effect
    rule: ClassVar[str] = "any record: every record can test it"
    #: the /api/sweeps body (without ``axes``) whose data would test the effect. An effect does not
    #: know the stage's range: a step body gives ``level_shares`` (0…1 of the drive range the data
    #: span, 0 its low end), never volts; service.science.discovery.identifiability.experiment_body
    #: places them on that range as ``levels_v`` (and a sine spans it); a sine above the data's rates
    #: gives ``rate_multiples`` of the data's fastest drive rate instead of ``frequencies_hz``
    sweep: ClassVar[dict] = RATE_SWEEP
    #: the sweep drives both axes, one at a time (an effect of the other axis)
    sweep_both_axes: ClassVar[bool] = False
    #: how a feedforward inverse undoes it: one of INVERSE_KINDS
    inverse: ClassVar[str] = "iterate"
    #: why there is no inverse (``inverse = "none"``)
    no_inverse: ClassVar[str] = ""
    #: the emulator's bench config (fixtures/benches/<name>.toml) that shows the effect, if there is one
    emulator_bench: ClassVar[str | None] = None
    #: a claim must also hold at the drive rates between the others, fitted without them
    #: (service.science.discovery.diagnosis: per-segment rate terms give loop-shape freedom)
    unseen_rate_test: ClassVar[bool] = False
    #: a time effect: its claim must hold beyond a gain that changes linearly with time
    #: (service.science.discovery.decision.less_gain_change: creep's slow lags drew a fading gain)
    gain_change_test: ClassVar[bool] = False
    #: capacity: the base's play operators are multiplied by this when the effect is in the model
    operator_factor: ClassVar[int] = 1
    #: transforms: the parameters for which the transform is the identity (where a search starts)
    identity: ClassVar[dict] = {}
    #: capacity levels this one is an alternative to: it is a candidate only while none of them is in
    #: the model (two grids of one base, chosen between on held-out data, never stacked)
    alternative_to: ClassVar[tuple[str, ...]] = ()
    #: a later alternative adds a kind of memory the earlier ones lack (a slow relaxation that may draw
    #: part of a creep): it comes before the physics only where it reaches the noise floor itself
    #: (service.science.discovery.base_capacity); False: it only refines the earlier grid's own maps
    adds_memory: ClassVar[bool] = True
    #: part of the flexible rate-independent base every physical candidate must beat (diagnosis)
    in_flexible_base: ClassVar[bool] = False
    #: a disturbance the record's rests show (a line at rest): the diagnosis takes it out of the record
    #: before the model is judged and names this effect for it, the rests' held-out test its evidence
    seen_at_rest: ClassVar[bool] = False
    #: an amplifier's rate limit: a remainder's words name an amplifier that cannot follow only where
    #: such an effect's own rule (``untestable``) lets it act on the records
    #: (service.science.discovery.remainder)
    limits_rate: ClassVar[bool] = False
    #: look-alikes: other effect -> (how to tell them apart in words, the /api/sweeps body that does;
    #: a step body's levels as ``level_shares``, as in ``sweep``)
    separated_from: ClassVar[dict[str, tuple[str, dict]]] = {}

    def setup(self, records) -> dict:
        """Constants (JSON types, units in the keys) learned from the records a model is fitted on,
        before any fit; a model stores them and its ``RecordContext.learned[name]`` gives them back."""
        return {}

    def drive(self, u_v: np.ndarray, fs_hz: float, theta: dict) -> np.ndarray:
        """Stage ``drive``: the drive (V) the stack sees for the planned ``u_v`` (V) at ``fs_hz``."""
        return u_v

    def untestable(self, records) -> str | None:
        """Why ``records`` cannot test this effect (in words), or None when they can."""
        return None

    def evidence(self, sig: dict, floor: dict) -> str:
        """What the residual shows that points at this effect, in words (``sig``: the diagnosis's
        signatures, service.science.discovery.breakdown; ``floor``: its noise floor, µm)."""
        return self.signature

    def response(self, frequency_hz: np.ndarray, fs_hz: float, theta: dict) -> np.ndarray:
        """Transforms with ``inverse = "response"``: the complex frequency response at ``frequency_hz``."""
        raise NotImplementedError(f"{self.name} has no frequency response")

    def blocks(self, ctx: RecordContext) -> list[Block]:
        """Additive regressor blocks (stage ``additive``)."""
        return []

    # -- transforms (stage "transform") -----------------------------------------------
    def grid(self, fs_hz: float, min_period_s: float, max_frequency_hz: float) -> list[dict]:
        """Candidate values of the nonlinear parameters for the outer search."""
        return [{}]

    def apply(self, columns: np.ndarray, fs_hz: float, theta: dict) -> np.ndarray:
        """The transform applied to columns (n, p)."""
        return columns

    #: transforms whose output at a row reads their input at a few rows (``taps``: a delay) get an
    #: exact search, applied after the others at the rows a fit reads
    row_local: ClassVar[bool] = False

    def apply_rows(self, columns: np.ndarray, fs_hz: float, theta: dict, rows: np.ndarray) -> np.ndarray:
        """The transform's output at ``rows`` (rising sample indices) only."""
        return self.apply(columns, fs_hz, theta)[rows]

    def taps(self, fs_hz: float, theta: dict, rows: np.ndarray, n: int) -> tuple:
        """Row-local transforms: ``((weight, input_rows), ...)`` such that the output at ``rows`` of
        an n-sample record is ``sum_of_taps`` of them over its columns."""
        raise NotImplementedError(f"{self.name} is not row-local")

    def clamp(self, theta: dict, fs_hz: float) -> dict:
        """``theta`` moved into this transform's valid range (a joint search may step outside it)."""
        return theta

    def refine(self, theta: dict, cost, fine: bool = False, bracket: tuple[dict, dict] | None = None) -> dict:
        """Optional local refinement around the best grid value; ``cost(theta) -> float``; ``bracket``:
        the grid values beside it (a 1-D grid's neighbours), where there are."""
        return theta

    def describe(self, theta: dict, values: dict) -> str:
        """Fitted parameters in words (units in the text)."""
        return ""

    def parameters(self, theta: dict, values: dict, scales: dict, sign: float) -> dict[str, float]:
        """Fitted physical parameters as numbers, units in the names (``theta`` this effect's transform
        parameters, ``values`` the model's fitted weights by block name, ``scales`` the model's drive and
        time scales, ``sign`` its gauge sign). Empty for an effect without a physical figure."""
        return {}
