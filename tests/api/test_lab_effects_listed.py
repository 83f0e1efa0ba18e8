"""GET /api/effects lists issue 38 §3's built-ins with their origin, parameters with units, rules and
inverse (a plain "none" with its reason for the line and the rate limit)."""

from __future__ import annotations


def test_the_lab_effects_are_listed_as_builtins(tmp_path):
    from service.http.app import create_app
    from service.runtime.settings import Settings
    from tests.support.api_client import authed_client

    with authed_client(create_app(Settings(data_dir=tmp_path, seed=0))) as http:
        r = http.get("/api/effects")
        assert r.status_code == 200, r.text
        by_name = {e["name"]: e for e in r.json()["effects"]}
    expect = {
        "line_disturbance": ("additive", "none", {"line_um": "µm", "line_hz": "Hz"}),
        "gain_change": ("additive", "iterate", {"gain_change_um": "µm", "gain_change_pct_per_s": "%/s"}),
        "slew_limit": ("drive", "none", {"slew_kv_per_s": "kV/s"}),
    }
    for name, (stage, inverse, units) in expect.items():
        e = by_name[name]
        assert (e["origin"], e["stage"], e["inverse"], e["emulator_bench"]) == ("builtin", stage, inverse, name)
        assert {p["name"]: p["unit"] for p in e["parameters"]}.items() >= units.items()
        assert e["rule"] and e["signature"] and (inverse != "none" or e["no_inverse"])
