"""Stages hiding an effect outside the built-in library (tests/support/open_world.py, built without
the product's code): what `discover` ends with and what it says about what remains."""

from __future__ import annotations

import warnings

import pytest

from tests.support.open_world import NOT_LOOP_SHAPE, measure

pytestmark = pytest.mark.slow  # one discover run each (about 40 s on a loaded 2-core machine)


def test_lines_seen_at_rest_are_out_of_every_fit_the_loop_compares():
    """A 50 Hz and a 37.3 Hz line (10 and 8 nm) on a Prandtl–Ishlinskii stage recorded with rests:
    the loop fitted and compared its steps on the record with the lines still in, so adding the
    operators the stage needs "raised" the held-out RMS and it stopped at 4.69× the floor."""
    warnings.simplefilter("ignore")
    row = measure("maxwell_slip", "two_lines", seed=0)
    assert row["end_to_floor"] <= 1.5, row
    assert set(row["added"]) <= NOT_LOOP_SHAPE, row  # a disturbance not locked to the drive: no loop shape
