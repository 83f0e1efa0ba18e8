"""The one record type every model fits, predicts and is validated on, with all input validation.

A :class:`Record` is one axis of one contiguous measurement from a relaxed state: the drive
``u_v`` (V), the displacement ``x_um`` (µm; None for a drive to predict from) and
``sample_rate_hz``. Optionally it carries the commanded waveform's exact rates, its block table
(a sweep's, or the one an import would cut: service.science.data.segmentation), the axis, the
other axis's drive and displacement (cross-coupling), and whether the last cycles of every block
are held out for validation (service.science.data.holdout).
Pure numpy: no model, no store, no HTTP.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from service.science.data.holdout import HELD_OUT_FRACTION, BlockSplit, split_blocks, training_mask
from service.science.data.segmentation import blocks_without_table
from service.science.data.signals import Waveform, dominant_period_samples, drive_derivatives

#: Fewer samples per dominant cycle than this cannot resolve a hysteresis loop.
MIN_SAMPLES_PER_CYCLE = 20
#: keep at least this many samples per cycle in the rows a decimated fit uses (``fit_rows``)
FIT_SAMPLES_PER_CYCLE = 400
#: rows a decimated fit keeps of one non-periodic block (a step-hold: slow, so evenly decimated), and
#: at most this many per second of it (a lab's six half-second holds at 20 kHz gave 4000 rows each,
#: outweighing all the sine blocks' rows and doubling a discovery's time, for the same figures)
MAX_STEP_ROWS = 4000
MAX_STEP_ROWS_PER_S = 1000.0


def finite_array(name: str, values, label: str = "") -> np.ndarray:
    """``values`` as a 1-D float array; ``ValueError`` naming ``name`` if it is not finite."""
    where = f"record '{label}': " if label else ""
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"{where}{name} must be 1-D, got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"{where}{name} is empty")
    problems = []
    for kind, mask in (("NaN", np.isnan(arr)), ("infinite", np.isinf(arr))):
        bad = np.flatnonzero(mask)
        if bad.size:
            shown = ", ".join(str(i) for i in bad[:5]) + (", ..." if bad.size > 5 else "")
            plural = "s" if bad.size > 1 else ""
            problems.append(f"{bad.size} {kind} value{plural} at sample{plural} {shown}")
    if problems:
        raise ValueError(f"{where}{name} contains " + " and ".join(problems))
    return arr


class Record:
    """One contiguous record of one axis, from a relaxed state.

    ``u_v`` drive (V), ``x_um`` displacement (µm, None for a drive to predict from),
    ``sample_rate_hz`` (Hz). Keyword-only: ``du_v_per_s``/``ddu_v_per_s2`` the commanded
    waveform's exact rates (else estimated, see :meth:`derivatives`); ``blocks`` the block table
    (None or empty: cut as an import would be); ``axis``; ``u_other_v``/``x_other_um`` the other
    axis's drive (V) and measured displacement (µm); ``hold_out`` True to keep the last ⌈20 %⌉
    cycles of every block out of a fit (validation), False to fit every row.
    """

    def __init__(
        self,
        u_v,
        x_um,
        sample_rate_hz: float,
        *,
        du_v_per_s=None,
        ddu_v_per_s2=None,
        label: str = "",
        blocks: list | None = None,
        axis: str | None = None,
        u_other_v=None,
        x_other_um=None,
        hold_out: bool = False,
        temp_c=None,
        rated_rate_v_per_s: float | None = None,
    ):
        where = f"record '{label}': " if label else ""
        try:
            fs = float(sample_rate_hz)
        except (TypeError, ValueError):
            raise ValueError(f"{where}sample_rate_hz must be a number, got {sample_rate_hz!r}") from None
        if not np.isfinite(fs) or fs <= 0:
            raise ValueError(f"{where}sample_rate_hz must be positive and finite, got {sample_rate_hz}")
        u = finite_array("u_v", u_v, label)
        arrays = {}
        for name, values in (
            ("x_um", x_um),
            ("du_v_per_s", du_v_per_s),
            ("ddu_v_per_s2", ddu_v_per_s2),
            ("u_other_v", u_other_v),
            ("x_other_um", x_other_um),
            ("temp_c", temp_c),
        ):
            arrays[name] = None if values is None else finite_array(name, values, label)
            if arrays[name] is not None and arrays[name].size != u.size:
                raise ValueError(f"{where}u_v has {u.size} samples but {name} has {arrays[name].size}")
        if (arrays["du_v_per_s"] is None) != (arrays["ddu_v_per_s2"] is None):
            raise ValueError(f"{where}give both du_v_per_s and ddu_v_per_s2, or neither")
        if np.ptp(u) == 0.0:
            raise ValueError(f"{where}u_v is constant ({u[0]:.6g} V): it excites no hysteresis")
        period = dominant_period_samples(u)
        if period < MIN_SAMPLES_PER_CYCLE:
            raise ValueError(
                f"{where}u_v has only {period:.1f} samples per cycle (dominant period "
                f"{period / fs * 1e3:.4g} ms at {fs:g} Hz); at least {MIN_SAMPLES_PER_CYCLE} are needed"
            )
        self.u_v, self.x_um, self.sample_rate_hz, self.label = u, arrays["x_um"], fs, str(label)
        self.u_other_v, self.x_other_um = arrays["u_other_v"], arrays["x_other_um"]
        self.temp_c = arrays["temp_c"]  #: the stack's temperature (°C) where a thermometer read it
        #: the fastest the amplifier was rated to move the stack's voltage when this was recorded (V/s: its
        #: current limit over the stack's capacitance, or its slew rating if lower); None when unknown (imports)
        self.rated_rate_v_per_s = None if rated_rate_v_per_s is None else float(rated_rate_v_per_s)
        self.axis, self.hold_out = axis, bool(hold_out)
        self._table = list(blocks) if blocks else None
        self._dominant_period = period
        self._derivatives = None if arrays["du_v_per_s"] is None else (arrays["du_v_per_s"], arrays["ddu_v_per_s2"])
        self.analytic_derivatives = self._derivatives is not None
        self._splits: dict[bool, list[BlockSplit]] = {}

    @classmethod
    def from_waveform(cls, waveform: Waveform, x_um=None, label: str = "") -> Record:
        """A record of a commanded waveform, carrying its exact rates."""
        return cls(
            waveform.value,
            x_um,
            waveform.sample_rate_hz,
            du_v_per_s=waveform.d1_per_s,
            ddu_v_per_s2=waveform.d2_per_s2,
            label=label,
        )

    def with_x(self, x_um, label: str | None = None) -> Record:
        """The same drive (and everything else) with another displacement record."""
        du, ddu = self._derivatives if self.analytic_derivatives else (None, None)
        return Record(
            self.u_v,
            x_um,
            self.sample_rate_hz,
            du_v_per_s=du,
            ddu_v_per_s2=ddu,
            label=self.label if label is None else label,
            blocks=self._table,
            axis=self.axis,
            u_other_v=self.u_other_v,
            x_other_um=self.x_other_um,
            hold_out=self.hold_out,
            temp_c=self.temp_c,
            rated_rate_v_per_s=self.rated_rate_v_per_s,
        )

    # -- shape and time ---------------------------------------------------------------
    @property
    def n_samples(self) -> int:
        return self.u_v.size

    @property
    def t_s(self) -> np.ndarray:
        return np.arange(self.n_samples) / self.sample_rate_hz

    @property
    def dominant_period_s(self) -> float:
        return self._dominant_period / self.sample_rate_hz

    # -- derivatives ------------------------------------------------------------------
    def derivatives(self) -> tuple[np.ndarray, np.ndarray]:
        """(u̇ in V/s, ü in V/s²): exact if given, else Savitzky–Golay per block of the block
        table over that block's own period (service.science.data.signals.drive_derivatives)."""
        if self._derivatives is None:
            self._derivatives = drive_derivatives(self.u_v, self.sample_rate_hz, self.blocks)
        return self._derivatives

    @property
    def du_v_per_s(self) -> np.ndarray:
        return self.derivatives()[0]

    @property
    def ddu_v_per_s2(self) -> np.ndarray:
        return self.derivatives()[1]

    # -- blocks and the held-out split --------------------------------------------------
    @property
    def blocks(self) -> list[dict]:
        """The block table: as given, or (none given) cut as an import would be, over both axes."""
        if self._table is None:
            axis = self.axis or "y"
            drives = {axis: self.u_v}
            if self.u_other_v is not None:
                drives[{"y": "z", "z": "y"}.get(axis, "other")] = self.u_other_v
            self._table = blocks_without_table(drives, self.sample_rate_hz)
        return self._table

    def splits_of(self, own_axis_only: bool = False) -> list[BlockSplit]:
        """Train/held-out ranges of every block (``own_axis_only``: only the blocks that drive this
        record's axis); without ``hold_out`` whole blocks train and nothing is held out."""
        if own_axis_only not in self._splits:
            axis = self.axis if own_axis_only else None
            fraction = HELD_OUT_FRACTION if self.hold_out else 0.0
            self._splits[own_axis_only] = split_blocks(self.blocks, self.n_samples, self.sample_rate_hz, axis, fraction)
        return self._splits[own_axis_only]

    @property
    def splits(self) -> list[BlockSplit]:
        """Every block's split, also blocks that drive only the other axis (they show coupling)."""
        return self.splits_of()

    def training_mask(self, own_axis_only: bool = False) -> np.ndarray:
        """The rows a fit learns from: training rows of the blocks when held out, else every row."""
        if not self.hold_out:
            return np.ones(self.n_samples, dtype=bool)
        return training_mask(self.splits_of(own_axis_only), self.n_samples)

    def period_samples(self, split: BlockSplit | None = None) -> float | None:
        """Samples per cycle: of the whole record's dominant cycle (no ``split``), or of one block
        (from its frequency; for a block the table could not time, the dominant period of its
        rows; None for steps and other non-periodic blocks)."""
        if split is None:
            return self._dominant_period
        f = split.block.get("frequency_hz")
        if f:
            return self.sample_rate_hz / float(f)
        if split.block.get("kind") not in (None, "imported"):
            return None
        a, b = split.train[0], split.held_out[1]
        return float(dominant_period_samples(self.u_v[a:b]))

    def min_period_s(self) -> float:
        """The shortest block period (s), or the dominant one if no block is periodic."""
        periods = [p for p in (self.period_samples(s) for s in self.splits) if p]
        return (min(periods) if periods else float(dominant_period_samples(self.u_v))) / self.sample_rate_hz

    def fit_rows(self, exclude_frequency_hz: float | None = None) -> np.ndarray:
        """Indices of the training rows a decimated fit uses: every block's training rows, decimated
        to about FIT_SAMPLES_PER_CYCLE samples per cycle (blocks at ``exclude_frequency_hz`` left out)."""
        rows = []
        for s in self.splits:
            if exclude_frequency_hz is not None and s.block.get("frequency_hz") == exclude_frequency_hz:
                continue
            period = self.period_samples(s)
            span = s.train[1] - s.train[0]
            step_stride = max(1, span // MAX_STEP_ROWS, int(self.sample_rate_hz // MAX_STEP_ROWS_PER_S))
            stride = max(1, int(period // FIT_SAMPLES_PER_CYCLE)) if period else step_stride
            rows.append(np.arange(s.train[0], s.train[1], stride))
        return np.concatenate(rows) if rows else np.zeros(0, dtype=int)

    def require_x(self) -> np.ndarray:
        if self.x_um is None:
            raise ValueError(f"record '{self.label}' has no x_um: a displacement record is needed to fit")
        return self.x_um

    # -- names kept for discovery modules written before the merge (use the names above) --
    @property
    def fs_hz(self) -> float:
        """Deprecated alias of ``sample_rate_hz``."""
        return self.sample_rate_hz

    @property
    def n(self) -> int:
        """Deprecated alias of ``n_samples``."""
        return self.n_samples

    @property
    def du(self) -> np.ndarray:
        """Deprecated alias of ``du_v_per_s``."""
        return self.du_v_per_s

    @property
    def ddu(self) -> np.ndarray:
        """Deprecated alias of ``ddu_v_per_s2``."""
        return self.ddu_v_per_s2

    def __repr__(self) -> str:
        return f"Record(label={self.label!r}, n_samples={self.n_samples}, sample_rate_hz={self.sample_rate_hz:g})"


def as_record_list(data: Record | Iterable[Record]) -> list[Record]:
    """A Record or an iterable of them as a non-empty list (fitted jointly)."""
    items = [data] if isinstance(data, Record) else list(data)
    if not items:
        raise ValueError("no data: give a Record or a non-empty list of Records")
    for i, s in enumerate(items):
        if not isinstance(s, Record):
            raise ValueError(f"data[{i}] is {type(s).__name__}, expected Record")
    return items
