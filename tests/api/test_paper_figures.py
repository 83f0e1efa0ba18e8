"""The seed paper's figures have one source (service/science/paper.py): GET /api/paper serves it,
the reports read it, and the dashboard's pages hold no copy of their own."""

from __future__ import annotations

from pathlib import Path

from service.http.app import create_app
from service.reports import calibration, reproduction, tracking
from service.runtime.settings import Settings
from service.science import paper
from service.science.control.session import PAPER_PID
from tests.support.api_client import authed_client

ROOT = Path(__file__).resolve().parents[2]


def test_the_api_serves_table6_and_the_tracking_cases(tmp_path):
    with authed_client(create_app(Settings(data_dir=tmp_path, seed=0))) as client:
        answer = client.get("/api/paper")
    assert answer.status_code == 200
    body = answer.json()
    z100 = next(r for r in body["table6_rms_um"]["z"] if r["frequency_hz"] == 100.0)
    assert (z100["dynamic_pi"], z100["grpi"], z100["static_pi"]) == (0.1039, 0.1326, 0.1513)
    assert body["tracking_cases"]["case1"]["max_error_um"] == {"y": 0.308, "z": 0.369}
    assert body["tracking_cases"]["case2"]["body"]["inclination_deg"] == 20
    assert body["fem_first_mode_hz"] == {"y": 482.6, "z": 290.7}
    assert body["pid_gains"]["z"] == {"kp": 70.0, "ki": 450.0, "kd": 0.08}


def test_reports_and_control_read_the_one_source():
    assert reproduction.PAPER_TABLE6_UM is paper.TABLE6_RMS_UM
    assert calibration.PAPER["z"]["pi_rms_100hz_um"] == paper.TABLE6_RMS_UM["z"][100.0][2]
    assert tracking.PAPER["case2"] == (0.154, 0.252)
    assert tracking.CASES["case1"] is paper.TRACKING_CASES["case1"]["body"]
    assert {axis: {"kp": g.kp, "ki": g.ki, "kd": g.kd} for axis, g in PAPER_PID.items()} == paper.PID_GAINS


def test_no_page_of_the_dashboard_copies_the_figures():
    for script in (ROOT / "web" / "js").rglob("*.js"):
        text = script.read_text()
        for figure in ("0.1513", "0.0586", "0.308", "0.369", "482.6", "290.7"):
            assert figure not in text, f"{script.relative_to(ROOT)} copies the paper's {figure}"
