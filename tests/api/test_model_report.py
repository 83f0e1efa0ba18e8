"""Issue 20 §3: GET /api/models/{id}/report, one self-contained HTML file, over REST on the creep
bench (a 4-frequency two-axis sweep, a static PI refined with creep); the CLI's ``models ID
--report FILE``; and the report's SVG charts and reproduce commands as units."""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import warnings
from html import unescape

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.frontends.cli_remote import _models
from service.frontends.client import Client
from service.http.app import create_app
from service.render.model_report import WORST_MARK
from service.render.reproduce import commands, dataset_request, refine_body
from service.render.svg import MAX_CURVE_POINTS, Panel, figure, nice_ticks
from service.runtime.settings import Settings
from service.science.data.units import fmt_nm
from tests.support.api_client import authed_client, bearer, issue_token, wait_job

SWEEP = {"axes": ["y", "z"], "frequencies_hz": [1, 10, 50, 100], "cycles": 5, "together": False}
#: The tests that read the module's ``refined`` service run on one xdist worker, which builds it once.
SHARED = pytest.mark.xdist_group("model_report_refined")


def _result(http, job_id) -> dict:
    job = wait_job(http, job_id, timeout_s=300)
    assert job["state"] == "succeeded", job
    return job["result"]


@pytest.fixture(scope="module")
def refined(tmp_path_factory):
    """The creep bench's sweep, a static PI of Y and its +creep refinement, and the refined model's
    report fetched with a read-scope token: {"http", "read", "dataset", "base", "model", "report"}."""
    warnings.simplefilter("ignore")
    settings = Settings(data_dir=tmp_path_factory.mktemp("report"), bench="creep", seed=0)
    with authed_client(create_app(settings)) as http:
        dataset = _result(http, http.post("/api/sweeps", json=SWEEP).json()["job_id"])["dataset_id"]
        body = {"axis": "y", "datasets": [dataset], "effects": ["hysteresis"]}
        base = _result(http, http.post("/api/models", json=body).json()["job_id"])["model_id"]
        refine = http.post(f"/api/models/{base}/refine", json={"add": "creep"})
        model = _result(http, refine.json()["job_id"])["model_id"]
        labelled = http.patch(f"/api/models/{model}", json={"name": "creep <Y>", "tags": ["paper", "a&b"]})
        assert labelled.status_code == 200, labelled.text
        read = TestClient(http.app, headers=bearer(issue_token(settings, "read")))
        report = read.get(f"/api/models/{model}/report", params={"download": "true"})
        yield {"http": http, "read": read, "dataset": dataset, "base": base, "model": model, "report": report}


def _printed_um(text: str) -> float:
    """A printed length ('6.097 nm', '1.234 µm') in µm."""
    value, unit = text.split()
    return float(value) * {"nm": 1e-3, "µm": 1.0}[unit]


def _as_printed(value_um: float) -> str:
    """How the report prints an error: 4 significant digits in nm, without an exponent."""
    return f"{float(f'{value_um * 1e3:.4g}'):g} nm"


@pytest.mark.slow
@SHARED
def test_the_report_of_a_refined_model(refined):
    r, http, model = refined["report"], refined["http"], refined["model"]
    assert r.status_code == 200, r.text
    assert r.headers["content-type"].startswith("text/html")
    assert r.headers["content-disposition"] == f'attachment; filename="{model}-report.html"'
    html = r.text
    print(f"report of a 4-frequency two-axis sweep model: {len(r.content) / 1024:.0f} kB")
    assert len(r.content) < 400 * 1024
    assert "<td>creep &lt;Y&gt;</td>" in html and "<td>paper, a&amp;b</td>" in html  # labels, escaped
    # self-contained: no script, nothing fetched from elsewhere
    assert "<script" not in html and not re.search(r'\s(src|href)="', html)

    # figures: one per Y block (the 4 frequencies) plus the error history, each with polylines
    figures = re.findall(r'<svg [^>]*class="figure".*?</svg>', html, flags=re.S)
    titles = [unescape(t) for t in re.findall(r'<svg [^>]*aria-label="([^"]*)"', html)]
    assert len(figures) == 4 + 1, titles
    assert titles[0].startswith("error history")
    marked = [t for t in titles[1:] if t.startswith(WORST_MARK)]
    assert len(marked) == 1 and html.count('class="block-figure worst"') == 1, titles  # the worst printed
    assert [t.removeprefix(WORST_MARK).split(" (held-out")[0] for t in titles[1:]] == [
        f"Y {f} Hz sine" for f in (1, 10, 50, 100)
    ]
    assert all("held-out cycle 5)" in t for t in titles[1:])  # 5 cycles: the last one held out
    for svg in figures:
        lines = re.findall(r'<polyline points="([^"]*)"', svg)
        assert lines and all(0 < len(p.split()) <= MAX_CURVE_POINTS for p in lines)

    # the lineage: steps and their RMS as GET /history gives them, to the printed precision
    steps = http.get(f"/api/models/{model}/history").json()["steps"]
    assert [s["model_id"] for s in steps] == [refined["base"], model] and [s["step"] for s in steps] == [0, 1]
    lineage = html[html.index('id="lineage"') :]
    for cls, key in (("rms-heldout", "validation_rms_um"), ("rms-train", "train_rms_um")):
        printed = re.findall(rf'class="{cls}">([^<]*)<', lineage)[: len(steps)]
        assert printed == [_as_printed(s[key]) for s in steps]
        for text, step in zip(printed, steps):
            digit = 10 ** (math.floor(math.log10(abs(float(text.split()[0])))) - 3)
            assert abs(_printed_um(text) - step[key]) <= 0.5 * digit * (1e-3 if "nm" in text else 1) * 1.0001
    assert "+creep" in lineage

    # the diagnosis: the same verdict and words as GET /diagnosis; the noise floor scaled
    d = http.get(f"/api/models/{model}/diagnosis").json()
    assert re.search(r'data-verdict="([^"]*)"', html)[1] == d["verdict"]
    assert unescape(re.search(r'<p id="verdict-text">([^<]*)</p>', html)[1]) == d["verdict_text"]
    assert re.search(r'id="noise-floor">([^<]*)<', html)[1] == _as_printed(d["noise_floor_um"])
    for c in d["candidates"][:3]:
        assert f"<td>{c['effect']}</td>" in html

    # fitted parameters: every coefficient group of the stored model, with its values
    stored = http.get(f"/api/models/{model}").json()["parameters"]
    for name, values in stored["coef"].items():
        row = re.search(rf"<code>coef\.{name}</code></td><td class=\"num\">(\d+)</td><td>([^<]*)<", html)
        assert row and int(row[1]) == len(values)
        assert np.allclose([float(v) for v in row[2].split(", ")], values, rtol=1e-5, atol=1e-12)

    # the physical parameters, each with its unit, as Discover's "Effects found" and the Lab page print them
    # (the creep's nm/decade was missing from the report)
    compared = http.get("/api/lab/compare", params={"axis": "y"}).json()["benches"][0]["model"]
    assert compared["id"] == model
    physical = compared["parameters"]
    assert set(physical["creep"]) == {"creep_nm_per_decade", "creep_step_v", "creep_pct_per_decade"}, physical
    for name, unit in (
        ("creep_nm_per_decade", "nm/decade"),
        ("creep_step_v", "V"),
        ("creep_pct_per_decade", "%/decade"),
    ):
        cell = re.search(rf'data-parameter="creep\.{name}" data-value="([^"]*)">([^<]*)</span> ([^<]*)</td>', html)
        assert cell, name
        assert float(cell[1]) == physical["creep"][name] and cell[3] == unit, (name, cell.groups())
        assert float(cell[2]) == pytest.approx(physical["creep"][name], rel=5e-4)  # 4 significant digits
    assert 2.0 < physical["creep"]["creep_pct_per_decade"] < 4.0  # fixtures/benches/creep.toml: 3 %/decade
    assert "<tr><td>creep</td><td>physics</td><td><code>creep_nm_per_decade</code>" in html  # its role beside it

    # the commands that reproduce it: the sweep's stored plan as the POST /api/sweeps body, the
    # identification and the refine step
    plan = http.get(f"/api/datasets/{refined['dataset']}").json()["plan"]
    curl = unescape(re.search(r'<pre id="reproduce-curl">(.*?)</pre>', html, flags=re.S)[1])
    sent = json.loads(re.search(r"post /sweeps '([^']*)'", curl)[1])
    assert sent == {**{k: v for k, v in plan.items() if k not in ("samples", "duration_s")}, "name": sent["name"]}
    assert sent["frequencies_hz"] == [1.0, 10.0, 50.0, 100.0] and sent["together"] is False
    assert """post /models '{"axis": "y", "datasets": ["'"$DS1"'"], "model": "static_pi\"""" in curl
    assert """post /models/$M1/refine '{"add": "creep"}'""" in curl
    python = unescape(re.search(r'<pre id="reproduce-python">(.*?)</pre>', html, flags=re.S)[1])
    assert "m2 = api.refine(m1, add='creep')[\"id\"]" in python and "api.sweep(**{" in python
    cli = unescape(re.search(r'<pre id="reproduce-cli">(.*?)</pre>', html, flags=re.S)[1])
    assert "evcbench sweep --axes y,z --frequencies 1,10,50,100 --separate" in cli
    assert "Print" in html and "PDF" in html


@pytest.mark.slow
@SHARED
def test_the_report_figures_alone_for_the_page(refined):
    """GET /report/figures: the report's own figures, named blocks, the worst of its printed held-out RMS marked."""
    r = refined["read"].get(f"/api/models/{refined['model']}/report/figures")
    assert r.status_code == 200, r.text
    fig = r.json()
    blocks = fig["blocks"]
    assert [b["title"].split(" (held-out")[0] for b in blocks] == [f"Y {f} Hz sine" for f in (1, 10, 50, 100)]
    assert all(b["svg"].startswith("<svg") and "<polyline" in b["svg"] for b in blocks)
    assert "<script" not in "".join(b["svg"] for b in blocks) + fig["history_svg"]
    assert "+creep" in fig["history_svg"] and "2× noise floor" in fig["history_svg"]
    worst = blocks[fig["worst_block"]]
    assert [b["worst"] for b in blocks].count(True) == 1 and worst["worst"]
    assert worst["svg"].count(WORST_MARK) == 3  # the figure's aria-label and <title>, its loop's title
    # the worst of the figures it prints (issue 39: it was the diagnosis's, of another fit)
    assert worst["held_out_rms_um"] == max(b["held_out_rms_um"] for b in blocks)
    assert f"held-out RMS {fmt_nm(worst['held_out_rms_um'])}" in worst["svg"]
    assert refined["http"].get("/api/models/md_nope/report/figures").status_code == 404


@pytest.mark.slow
@SHARED
def test_the_reproduce_commands_run(refined):
    """The Python lines, run as they are printed (the client on this service), record the sweep
    again and rebuild the lineage; the shell lines parse."""
    html = refined["report"].text
    python = unescape(re.search(r'<pre id="reproduce-python">(.*?)</pre>', html, flags=re.S)[1]).splitlines()
    assert python[2].startswith("api = Client(") and python[-1].startswith("open(")
    scope = {"api": Client(http=refined["http"])}
    exec("\n".join(python[:2] + python[3:-1]), scope)  # the same service; no report written here
    again = refined["http"].get(f"/api/models/{scope['m2']}").json()
    original = refined["http"].get(f"/api/models/{refined['model']}").json()
    assert again["effects"] == original["effects"] and again["parent_id"] == scope["m1"]
    assert again["datasets"] == [scope["ds1"]] and scope["ds1"] != refined["dataset"]
    assert again["metrics"]["validation_rms_um"] == pytest.approx(original["metrics"]["validation_rms_um"], rel=0.3)
    for key in ("curl", "cli"):
        text = unescape(re.search(rf'<pre id="reproduce-{key}">(.*?)</pre>', html, flags=re.S)[1])
        assert subprocess.run(["bash", "-n"], input=text, text=True, capture_output=True).returncode == 0, text


@pytest.mark.slow
@SHARED
def test_unknown_model_and_tokens(refined):
    read, model = refined["read"], refined["model"]
    r = read.get("/api/models/md_nope/report")
    assert r.status_code == 404 and r.json() == {"detail": "no model with id 'md_nope'", "field": "model"}
    anonymous = TestClient(read.app)
    r = anonymous.get(f"/api/models/{model}/report")
    assert r.status_code == 401 and r.json()["detail"]


@pytest.mark.slow
@SHARED
def test_cli_writes_the_report(refined, tmp_path, capsys):
    out = tmp_path / "report.html"
    args = argparse.Namespace(model_id=refined["model"], report=str(out), json=False)
    assert _models(Client(http=refined["http"]), args) == 0
    html = out.read_text(encoding="utf-8")
    assert html.startswith("<!DOCTYPE html>") and html.count('class="figure"') == 5
    assert f"report of {refined['model']}: {out}" in capsys.readouterr().out


# ------------------------------------------------------------------ units
def test_lengths_scale_and_text_is_escaped():
    assert fmt_nm(0.002945) == "2.95 nm"  # errors in nm, however large
    assert fmt_nm(0.5) == "500 nm" and fmt_nm(6.4) == "6400 nm" and fmt_nm(None) == "–"
    assert nice_ticks(0.0, 120.0) == [0.0, 20.0, 40.0, 60.0, 80.0, 100.0, 120.0]
    x = np.linspace(0, 1, 20_001)
    panel = Panel(400, 300, "a <b> & 'c'", "t (s)", "x (µm)").line(x, x**2, "y < 1")
    svg = figure([panel], 'label "q"')
    assert "<b>" not in svg and "a &lt;b&gt; &amp; &#x27;c&#x27;" in svg and "y &lt; 1" in svg
    points = re.search(r'<polyline points="([^"]*)"', svg)[1].split()
    assert len(points) <= MAX_CURVE_POINTS


def test_refine_bodies_and_dataset_requests():
    step = {"effects": ["hysteresis", "creep"], "datasets": ["ds_a", "ds_b"]}
    assert refine_body(step, {"effects": ["hysteresis"], "datasets": ["ds_a"]}) == {
        "add": "creep",
        "datasets": ["ds_b"],
    }
    assert refine_body(
        {"effects": ["hysteresis"], "datasets": ["ds_a"]}, {"effects": ["hysteresis", "delay"], "datasets": ["ds_a"]}
    ) == {"remove": "delay"}
    assert refine_body(
        {"effects": ["hysteresis", "creep", "drift"], "datasets": ["ds_a"]},
        {"effects": ["hysteresis", "delay"], "datasets": ["ds_a"]},
    ) == {"effects": ["hysteresis", "creep", "drift"]}
    sweep = {"source": "sweep", "name": "s", "plan": {"waveform": "sine", "cycles": 5, "samples": 9, "duration_s": 1}}
    assert dataset_request(sweep) == {"kind": "sweep", "body": {"waveform": "sine", "cycles": 5, "name": "s"}}
    chirp = {
        "source": "sweep",
        "name": "c",
        "sample_rate_hz": 1000.0,
        "plan": {"waveform": "chirp", "duration_s": 9.0},
        "blocks": [{"kind": "chirp", "start": 500, "stop": 8500}],
    }
    assert dataset_request(chirp)["body"] == {"waveform": "chirp", "duration_s": 8.0, "name": "c"}
    imported = {
        "source": "import",
        "name": "lab",
        "plan": {"import": {"filename": "a.csv", "axis": None}, "drive_range_v": {}},
    }
    assert dataset_request(imported) == {"kind": "import", "body": {"filename": "a.csv", "name": "lab"}}


def test_the_reports_lineage_numbers_its_steps_from_0():
    """One numbering (issue 39: 0-based on the Discover page, 1-based in the history table and the
    report): step 0 is the lineage's first model, in the table and the error history's x axis."""
    from service.render.model_report import _lineage_section

    steps = [
        {"step": k, "model_id": f"mdl_{k}", "change": change, "effects": ["hysteresis", *extra]}
        | {"train_rms_um": rms, "validation_rms_um": rms, "like_for_like_rms_um": rms}
        for k, (change, extra, rms) in enumerate(
            [(None, [], 0.02), ("+creep", ["creep"], 0.01), ("+drift", ["creep", "drift"], 0.008)]
        )
    ]
    html = _lineage_section(steps, 0.004)
    assert re.findall(r'<tr><td class="num">(\d+)</td><td><code>(mdl_\d)</code>', html) == [
        ("0", "mdl_0"),
        ("1", "mdl_1"),
        ("2", "mdl_2"),
    ]
    assert "first model (step 0)" in html and "lineage step (0: the first model)" in html


def test_a_stored_name_never_ends_a_script_comment(tmp_path):
    """A walk stored a dataset name with a line break ("nl\\ntouch FILE #", before names had to be one
    line): the reproduce script printed it in a comment, the line break ended the comment and the next
    line ran. The shell scripts, run with curl, jq and evcbench as stubs, run no such line; every
    comment is one line, and the name is kept in it."""
    pwned = tmp_path / "pwned"
    evil = f"nl\ntouch {pwned} #\r\u2028x"
    rows = [
        {"id": "ds_a", "source": "import", "name": evil, "plan": {"import": {"filename": "a\nb.csv"}}},
        {"id": "ds_b", "source": "sweep", "name": evil, "plan": {"waveform": "sine", "cycles": 5}},
    ]
    steps = [
        {"model_id": "mdl_1", "effects": ["hysteresis"], "datasets": ["ds_a", "ds_b"]},
        {"model_id": "mdl_2", "change": evil, "effects": ["hysteresis", "creep"], "datasets": ["ds_a", "ds_b"]},
    ]
    root = {"kind": "static_pi", "effects": ["hysteresis"], "options": {"n_operators": 10}, "axis": "y"}
    scripts = commands(rows, steps, root)
    for key in ("curl", "cli"):
        # every job "succeeded" at once: the helpers' wait loops end
        stubs = "curl() { echo '{}'; }; jq() { cat >/dev/null; echo succeeded; }; evcbench() { echo '{}'; }\n"
        ran = subprocess.run(
            ["bash", "-c", stubs + scripts[key]], text=True, capture_output=True, cwd=tmp_path, timeout=60
        )
        assert not pwned.exists(), (key, scripts[key], ran.stderr)
    for key, text in scripts.items():
        comments = [line for line in text.split("\n") if line.startswith("#")]
        assert sum(f"nl touch {pwned} #" in line for line in comments) >= 2, (key, text)  # the name, on one line
        assert not any("\r" in line or "\u2028" in line for line in comments), key


def test_names_and_tags_are_one_line(tmp_path):
    """PATCH, identify and import refuse a name or tag with a line break (422 naming the field), and
    nothing stored changes."""
    with authed_client(create_app(Settings(data_dir=tmp_path, bench="default", seed=0))) as http:
        files = {"file": ("lab.csv", "t,u,x\n" + "".join(f"{k / 1000},{k % 7},{(k % 7) * 0.1}\n" for k in range(400)))}
        refused = http.post("/api/datasets", files=files, data={"name": "a\nb", "axis": "y"})
        assert refused.status_code == 422 and refused.json()["field"] == "name", refused.text
        assert http.get("/api/datasets").json() == []
        dataset = http.post("/api/datasets", files=files, data={"name": "lab", "axis": "y"}).json()["id"]
        for body, field in (({"name": "x\ny"}, "name"), ({"tags": ["ok", "a\tb"]}, "tags")):
            answer = http.patch(f"/api/datasets/{dataset}", json=body)
            assert answer.status_code == 422 and answer.json()["field"] == field, answer.text
        assert http.get(f"/api/datasets/{dataset}").json()["name"] == "lab"
        answer = http.post("/api/models", json={"axis": "y", "datasets": [dataset], "name": "m\r"})
        assert answer.status_code == 422 and answer.json()["field"] == "name", answer.text


def test_a_capped_score_is_labelled_in_the_report():
    """A score of 1 that is a cap (its test's drop exceeds this model's excess) reads "1 (capped)"; a
    share reads bare (issue 39: the report printed a bare 1 beside a drop larger than its whole)."""
    from service.render.model_report import _diagnosis_section

    row = {"kind": "physical", "claimed": True, "evidence": "e", "expected_rms_um": 0.01, "score_of": "words"}
    capped = {**row, "effect": "drift", "score": 1.0, "score_capped": True}
    share = {**row, "effect": "creep", "score": 0.5, "score_capped": False}
    html = _diagnosis_section({"candidates": [capped, share], "residual_rms_um": 0.02})
    cells = re.findall(r"<td[^>]*>([^<]*)<br><small>words</small>", html)
    assert cells == ["1 (capped)", "0.5"], cells
