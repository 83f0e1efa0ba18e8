"""The record type every model fits and predicts, with all input validation in one place."""
from __future__ import annotations

from typing import Iterable

import numpy as np

from service.science.data.signals import Waveform, dominant_period_samples, savgol_derivatives

#: Fewer samples per dominant cycle than this cannot resolve a hysteresis loop.
MIN_SAMPLES_PER_CYCLE = 20


def finite_array(name: str, values, label: str = "") -> np.ndarray:
    """``values`` as a 1-D float array; ``ValueError`` naming ``name`` if it is not finite."""
    where = f"series '{label}': " if label else ""
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


class Series:
    """One contiguous record starting from a relaxed state.

    ``u_v`` actuator voltage (V), ``x_um`` measured displacement (µm, or None for a
    prediction-only record), ``sample_rate_hz`` (Hz). ``du_v_per_s``/``ddu_v_per_s2``
    are the commanded waveform's exact derivatives when known; otherwise they are
    estimated by Savitzky–Golay over a window set by the dominant period.
    """

    def __init__(
        self,
        u_v,
        x_um,
        sample_rate_hz: float,
        du_v_per_s=None,
        ddu_v_per_s2=None,
        label: str = "",
    ):
        where = f"series '{label}': " if label else ""
        try:
            fs = float(sample_rate_hz)
        except (TypeError, ValueError):
            raise ValueError(f"{where}sample_rate_hz must be a number, got {sample_rate_hz!r}") from None
        if not np.isfinite(fs) or fs <= 0:
            raise ValueError(f"{where}sample_rate_hz must be positive and finite, got {sample_rate_hz}")
        u = finite_array("u_v", u_v, label)
        others = {"x_um": x_um, "du_v_per_s": du_v_per_s, "ddu_v_per_s2": ddu_v_per_s2}
        arrays = {}
        for name, values in others.items():
            if values is None:
                arrays[name] = None
                continue
            arr = finite_array(name, values, label)
            if arr.size != u.size:
                raise ValueError(f"{where}u_v has {u.size} samples but {name} has {arr.size}")
            arrays[name] = arr
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
        self.u_v = u
        self.x_um = arrays["x_um"]
        self.sample_rate_hz = fs
        self.label = str(label)
        self.period_samples = period
        self._derivatives = (
            None if arrays["du_v_per_s"] is None else (arrays["du_v_per_s"], arrays["ddu_v_per_s2"])
        )
        self.analytic_derivatives = self._derivatives is not None

    @classmethod
    def from_waveform(cls, waveform: Waveform, x_um=None, label: str = "") -> "Series":
        """A record of a commanded waveform, carrying its exact derivatives."""
        return cls(waveform.value, x_um, waveform.sample_rate_hz, waveform.d1_per_s, waveform.d2_per_s2, label)

    def with_x(self, x_um, label: str | None = None) -> "Series":
        """The same drive with another displacement record."""
        du, ddu = self._derivatives if self.analytic_derivatives else (None, None)
        return Series(self.u_v, x_um, self.sample_rate_hz, du, ddu, self.label if label is None else label)

    @property
    def n_samples(self) -> int:
        return self.u_v.size

    @property
    def dominant_period_s(self) -> float:
        return self.period_samples / self.sample_rate_hz

    @property
    def t_s(self) -> np.ndarray:
        return np.arange(self.n_samples) / self.sample_rate_hz

    def derivatives(self) -> tuple[np.ndarray, np.ndarray]:
        """(u̇ in V/s, ü in V/s²): exact if given, else Savitzky–Golay estimates (cached)."""
        if self._derivatives is None:
            self._derivatives = savgol_derivatives(self.u_v, self.sample_rate_hz, self.period_samples)
        return self._derivatives

    def require_x(self) -> np.ndarray:
        if self.x_um is None:
            raise ValueError(f"series '{self.label}' has no x_um: a displacement record is needed to fit")
        return self.x_um

    def __repr__(self) -> str:
        return f"Series(label={self.label!r}, n_samples={self.n_samples}, sample_rate_hz={self.sample_rate_hz:g})"


def as_series_list(data: "Series | Iterable[Series]") -> list[Series]:
    """A Series or an iterable of them as a non-empty list (fitted jointly)."""
    items = [data] if isinstance(data, Series) else list(data)
    if not items:
        raise ValueError("no data: give a Series or a non-empty list of Series")
    for i, s in enumerate(items):
        if not isinstance(s, Series):
            raise ValueError(f"data[{i}] is {type(s).__name__}, expected Series")
    return items
