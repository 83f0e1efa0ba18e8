"""The measured data nobody on this project produced (../shared/data/real beside the repo).

Tests that use it fail when it is missing — a missing file is a broken checkout, not a reason to
pass quietly — unless EVCBENCH_SKIP_REAL_DATA=1 asks to skip them.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REAL_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"
#: yan9a-dbo: column 0 drive (V, amplifier input), column 4 gauge (µm, arbitrary zero), 200 Hz.
MODEL_VI_DO = REAL_DIR / "yan9a-dbo" / "Model_Vi_Do.dat"

requires_real_data = pytest.mark.skipif(os.environ.get("EVCBENCH_SKIP_REAL_DATA") == "1",
                                        reason="EVCBENCH_SKIP_REAL_DATA=1: real-data tests skipped on request")
