"""The measured data nobody on this project produced, vendored with its licence and a README that
gives its source and columns in fixtures/real/. A test that uses it fails if it is missing: a missing
file is a broken checkout, not a reason to pass quietly.
"""

from __future__ import annotations

from pathlib import Path

REAL_DIR = Path(__file__).resolve().parents[2] / "fixtures" / "real"
#: yan9a-dbo: column 0 drive (V, amplifier input), column 4 gauge (µm, arbitrary zero), 200 Hz.
MODEL_VI_DO = REAL_DIR / "yan9a-dbo" / "Model_Vi_Do.dat"
