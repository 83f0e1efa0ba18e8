"""The one model contract (issue 16), in the spirit of scikit-learn's estimator contract.

Every hysteresis model — the paper's static PI, dynamic PI and GRPI
(service.science.models) and the discovery composite (service.science.discovery.composite) —
is used through these members only; no caller asks which kind it holds.

- **Configuration** in the constructor (keyword arguments), returned by ``get_config()``;
  ``fit`` never changes it. ``is_fitted`` says whether the state is learned.
- ``fit(records) -> self``: learns the **state** (public attributes: weights, thresholds, …) from
  :class:`~service.science.data.record.Record` s. A record with ``hold_out`` keeps the last
  cycles of every block out of the fit (the paper's PI family learns from the blocks that drive
  the record's axis, the composite from every block: it explains the other axis's motion).
- ``predict(drive, sample_rate_hz=None) -> x_um``: ``drive`` is a Record (its rates, block
  table, other-axis drive and time base are used) or an array of volts, with ``sample_rate_hz``
  for a model that needs time (rate-dependent or dynamic). Relaxed state at the first sample.
- ``inverse(x_ref_um, *, sample_rate_hz=None, u_limits_v=None) -> u_v``: the drive (V) whose
  prediction follows ``x_ref_um`` (µm), searched within ``u_limits_v`` (V; None: the model's own
  range, :data:`UNBOUNDED_V` for the PI family). Models may take further keyword-only options.
- ``stack_demand_um(x_ref_um, sample_rate_hz)``: what the stack must deliver before the model's
  output dynamics (the reference itself for a model without them); ``judges_stroke``: True when
  the model carries those dynamics, so a range beyond the stroke by its inverse is refused, not
  only warned about (service.science.control.safety).
- ``evaluate(records)``: train and held-out RMS per block and their means;
  ``validate(records)``: the figures an identification stores (``evaluate`` and any extra
  held-out check the model offers).
- ``for_effects(effects, n_operators=…, parent=None)`` (classmethod): the model an
  identification of ``hysteresis + effects`` builds from this kind (ValueError naming
  ``effects`` if it cannot); ``described_effects``: the effects the model describes, hysteresis
  first (service.science.discovery.composite.as_composite: the composite discovery starts from).
- ``to_dict()`` → ``{"model": name, "config": {...}, **state}`` (JSON floats round-trip exactly);
  ``from_dict(d)`` rebuilds it (service.science.discovery.registry.model_from_dict for any kind).
"""

from __future__ import annotations

from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from service.science.data.record import Record, finite_array
from service.science.data.signals import drive_derivatives

#: the PI family's inverse search range (V) when none is given
UNBOUNDED_V = (-np.inf, np.inf)


class Drive:
    """What a model predicts from: ``u_v`` (V) at ``sample_rate_hz`` (Hz or None), its rates
    (a Record's, or estimated once over the dominant period), and the other axis's drive (V) and
    displacement (µm) and the stack's temperature ``temp_c`` (°C) when a Record has them."""

    def __init__(self, u_v, sample_rate_hz: float | None = None, record: Record | None = None):
        self.u_v = record.u_v if record is not None else finite_array("u_v", u_v)
        self.sample_rate_hz = record.sample_rate_hz if record is not None else sample_rate_hz
        self.record = record
        self.u_other_v = None if record is None else record.u_other_v
        self.x_other_um = None if record is None else record.x_other_um
        self.temp_c = None if record is None else record.temp_c
        self._estimated = None

    @classmethod
    def of(cls, drive, sample_rate_hz: float | None = None) -> Drive:
        """``drive`` (a Drive, a Record, or an array of volts at ``sample_rate_hz``) as a Drive."""
        if isinstance(drive, Drive):
            return drive
        if isinstance(drive, Record):
            return cls(None, record=drive)
        return cls(drive, sample_rate_hz)

    @property
    def n_samples(self) -> int:
        return self.u_v.size

    def require_rate(self) -> float:
        """The sample rate (Hz); ValueError naming ``sample_rate_hz`` when it is unknown."""
        fs = self.sample_rate_hz
        if fs is None or not float(fs) > 0:
            raise ValueError("sample_rate_hz (positive) is needed to estimate u̇ and ü for a rate-dependent model")
        return float(fs)

    def derivatives(self) -> tuple[np.ndarray, np.ndarray]:
        """(u̇ V/s, ü V/s²): the Record's, else Savitzky–Golay over the drive's dominant period."""
        if self.record is not None:
            return self.record.derivatives()
        if self._estimated is None:
            self._estimated = drive_derivatives(self.u_v, self.require_rate())
        return self._estimated


@runtime_checkable
class Model(Protocol):
    """The members every model provides (see the module docstring)."""

    name: ClassVar[str]
    judges_stroke: ClassVar[bool]

    @property
    def is_fitted(self) -> bool: ...

    def get_config(self) -> dict[str, Any]: ...

    def fit(self, records) -> Model: ...

    def predict(self, drive, sample_rate_hz: float | None = None) -> np.ndarray: ...

    def inverse(self, x_ref_um, *, sample_rate_hz: float | None = None, u_limits_v=None) -> np.ndarray: ...

    def stack_demand_um(self, x_ref_um, sample_rate_hz: float | None = None) -> np.ndarray: ...

    def evaluate(self, records) -> dict: ...

    def validate(self, records) -> dict: ...

    @property
    def described_effects(self) -> tuple[str, ...]: ...

    def to_dict(self) -> dict: ...

    @classmethod
    def for_effects(cls, effects, n_operators: int = 10, parent=None) -> Model: ...

    @classmethod
    def from_dict(cls, d: dict) -> Model: ...


def split_stored(d: dict, name: str, config_keys) -> tuple[dict, dict]:
    """(config, the rest) of a ``to_dict()``; a dict stored before the config was nested keeps
    its configuration at the top level. ValueError naming ``model`` if it is another kind."""
    if d.get("model") != name:
        raise ValueError(f"expected model {name!r}, got {d.get('model')!r}")
    if "config" in d:
        return dict(d["config"]), d
    return {k: d[k] for k in config_keys if k in d}, d
