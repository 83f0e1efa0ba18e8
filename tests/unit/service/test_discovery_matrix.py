"""The discovery matrix on the hysteresis families that are not the Preisach default (issue 17 §5),
through the same functions as ``python -m service.reports.discovery_matrix``: every hidden-effect
variant on Bouc–Wen and Maxwell-slip stacks (top candidate right and claimed, the refine halves the
held-out RMS), clean benches of every family with independent and collinear drives (nothing
physical claimed; collinear drives leave cross-coupling not testable), and several effects at once.
The Preisach variants are tests/unit/science/test_discovery_variants.py. Nothing here is tuned to a family: the
figures are the report's (docs/discovery-evidence.md)."""

from __future__ import annotations

import warnings

import pytest

from service.reports.discovery_matrix import CLEAN, EFFECTS, FAMILIES, SEVERAL, clean, one_effect, several

pytestmark = pytest.mark.slow  # each case is a sweep and a diagnosis: seconds


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


@pytest.mark.parametrize("bench,effect", [(FAMILIES[f] + e, e) for f in ("bouc_wen", "maxwell_slip") for e in EFFECTS])
def test_hidden_effect_on_another_family_is_named_and_fixed(bench, effect):
    row = one_effect(bench, effect)
    assert row["right"], (row["top"], row["claimed"])
    assert row["drop"] >= 0.5, row


@pytest.mark.parametrize("family", list(FAMILIES))
@pytest.mark.parametrize("together", [False, True], ids=["independent", "collinear"])
def test_clean_bench_claims_nothing(family, together):
    rows = clean(CLEAN[family], family, together, seed=0)
    assert {r["axis"] for r in rows} == {"y", "z"}
    assert not [r for r in rows if r["claimed"]], rows
    for r in rows:  # the other axis moved with this one: its coupling cannot be seen
        assert ("cross_coupling" in r["not_testable"]) == together, r


def test_two_hidden_effects_are_both_named_within_two_rounds_in_three_of_four():
    rows = [several(bench, hidden) for bench, hidden in SEVERAL.items() if len(hidden) == 2]
    assert len(rows) == 4 and sum(r["all_named"] for r in rows) >= 3, rows


def test_three_hidden_effects_are_named_within_three_rounds():
    rows = [several(bench, hidden) for bench, hidden in SEVERAL.items() if len(hidden) == 3]
    assert rows and all(r["all_named"] for r in rows), rows
