"""The columns fits share (service.science.discovery.column_memo): within a scope each effect's
blocks of one record context are built once and are read-only; the fits give the same numbers
with and without it; what a scope kept is released when it ends; the byte bound evicts."""

from __future__ import annotations

import numpy as np
import pytest

from service.science.data.record import Record
from service.science.discovery.column_memo import ColumnMemo, shared_effect_columns
from service.science.discovery.composite import CompositeModel
from service.science.effects import EFFECTS
from service.science.models.contract import Drive

FS = 5000.0


def _record() -> Record:
    t = np.arange(int(2.0 * FS)) / FS
    u = 60.0 + 50.0 * np.sin(2 * np.pi * 5.0 * t)
    x = 0.08 * u + 0.002 * np.abs(np.gradient(u)) + 1e-4 * (u - 60.0) ** 2
    return Record(u, x, FS, label="memo")


@pytest.fixture
def asymmetry_builds(monkeypatch):
    """How often the asymmetry effect's blocks are built (the real method, counted)."""
    calls = []
    real = type(EFFECTS["asymmetry"]).blocks
    monkeypatch.setattr(type(EFFECTS["asymmetry"]), "blocks", lambda self, ctx: calls.append(1) or real(self, ctx))
    return calls


def test_a_scope_builds_each_effects_blocks_once_and_the_fits_are_the_same(asymmetry_builds):
    record = _record()
    plain = [CompositeModel(["asymmetry", e]).fit([record]) for e in ("creep", "drift")]
    assert len(asymmetry_builds) == 2
    with shared_effect_columns():
        shared = [CompositeModel(["asymmetry", e]).fit([record]) for e in ("creep", "drift")]
        predicted = shared[0].predict(record)
    assert len(asymmetry_builds) == 3  # once for both fits and the prediction in the scope
    for a, b in zip(plain, shared):
        assert a.train_rms_um == b.train_rms_um
        assert all(np.array_equal(a.coef[k], b.coef[k]) for k in a.coef)
    assert np.array_equal(predicted, plain[0].predict(record))
    with shared_effect_columns():  # the last scope's columns are gone
        CompositeModel(["asymmetry"]).fit([record])
    assert len(asymmetry_builds) == 5  # the scope's fit, and plain[0].predict above


def test_shared_columns_are_read_only():
    record = _record()
    with shared_effect_columns():
        model = CompositeModel(["asymmetry"]).fit([record])
        blocks = model.raw_blocks(Drive.of(record))
    shared = next(b for b in blocks if b.name == "asymmetry_um")
    with pytest.raises(ValueError, match="read-only"):
        shared.parts[0][0, 0] = 1.0


def test_the_byte_bound_evicts_the_least_recently_used():
    memo = ColumnMemo(max_entries=10, max_bytes=3 * 800)
    sources = [np.zeros(3) for _ in range(4)]
    built = []

    def make(k):
        return lambda: built.append(k) or np.full(100, float(k))  # 800 bytes each

    for k in range(3):
        memo.get((sources[k],), (), make(k))
    memo.get((sources[0],), (), make(0))  # 0 is now the most recent
    memo.get((sources[3],), (), make(3))  # over the bound: 1 (least recent) goes
    memo.get((sources[0],), (), make(0))
    memo.get((sources[1],), (), make(1))
    assert built == [0, 1, 2, 3, 1]
