"""The measured data nobody on this project produced, vendored with its licence and a README that
gives its source and columns in fixtures/real/. A test that uses it fails if it is missing: a missing
file is a broken checkout, not a reason to pass quietly.
"""

from __future__ import annotations

from pathlib import Path

REAL_DIR = Path(__file__).resolve().parents[2] / "fixtures" / "real"
#: yan9a-dbo: column 0 drive (V, amplifier input), column 4 gauge (µm, arbitrary zero), 200 Hz.
MODEL_VI_DO = REAL_DIR / "yan9a-dbo" / "Model_Vi_Do.dat"


def import_model_vi_do(api) -> str:
    """POST the yan9a record to ``api`` (a client on /api) as a lab member imports it: columns 0 and 4,
    200 Hz, axis y, whitespace-separated; the new dataset's id (asserts the 201)."""
    with MODEL_VI_DO.open("rb") as f:
        answer = api.post(
            "/datasets",
            files={"file": ("Model_Vi_Do.dat", f)},
            data={"columns": '{"u":0,"x":4}', "sample_rate_hz": "200", "axis": "y", "delimiter": "whitespace"},
        )
    assert answer.status_code == 201, answer.text
    return answer.json()["id"]
