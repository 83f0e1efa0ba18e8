"""The model report: one self-contained HTML page (inline CSS and SVG, no script, no external
file) with the model, its data, its lineage, its diagnosis, its fitted parameters, a figure per
block (the loop over the held-out cycles, measured and predicted, and the residual) and the error
history, and the commands that reproduce it. Printing it from a browser gives a PDF with the
figures as vectors.

Pure rendering: it takes rows, dicts and decimated arrays (service.usecases.report gathers them),
and knows no store or HTTP.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from html import escape

import numpy as np

from service.render.model_facts import operators_text, physical_table, table_html, value_text, without_lines_fact
from service.render.svg import COLOURS, ERROR_UNIT, MAX_CURVE_POINTS, Panel, figure, length_unit
from service.science.data.units import fmt_nm, plain

CSS = """body{font-family:system-ui,sans-serif;max-width:1120px;margin:24px auto;padding:0 16px;color:#222}
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;padding-bottom:3px;margin-top:1.6em}
table{border-collapse:collapse;margin:6px 0;font-size:.9em}td,th{border:1px solid #ccc;padding:3px 7px;
vertical-align:top;text-align:left}td.num,th.num{text-align:right;font-variant-numeric:tabular-nums}
pre{background:#f5f5f5;padding:8px;overflow-x:auto;font-size:.8em;white-space:pre-wrap;word-break:break-all}
.muted{color:#666}.verdict{font-weight:600}svg.figure{display:block;max-width:100%;height:auto;margin:8px 0}
svg text{fill:#222}svg .title{font-weight:600;font-size:11.5px}footer{margin-top:2em;color:#666;font-size:.85em}
@media print{body{margin:0;max-width:none}pre{white-space:pre-wrap}svg.figure{page-break-inside:avoid}}"""

PDF_NOTE = (
    "For a PDF, open this file in a browser and print it to PDF (Print → Save as PDF): the "
    "figures are SVG and stay vectors. The file needs no network and no script."
)


@dataclass
class BlockCurves:
    """One block's held-out cycles, decimated: drive ``u_v`` (V), measured ``x_um`` and predicted
    ``x_model_um`` (µm) at times ``t_s`` (s, from the held-out start), with its RMS figures (µm,
    over every sample); ``block_index`` and ``frequency_hz`` as the dataset's block table has them."""

    title: str
    dataset_id: str
    block_index: int | None
    frequency_hz: float | None
    t_s: np.ndarray
    u_v: np.ndarray
    x_um: np.ndarray
    x_model_um: np.ndarray
    held_out_rms_um: float | None
    train_rms_um: float | None


#: the title's mark on the block with the largest held-out RMS of those the report prints
WORST_MARK = "▲ worst block: "


def block_figure(b: BlockCurves, axis: str, worst: bool = False) -> str:
    """The loop (x against u; measured and model) and the residual over time, side by side; the
    block with the largest held-out RMS (``worst``) has WORST_MARK before its title and a red frame."""
    factor, unit = length_unit(float(np.max(np.abs(b.x_um))) if b.x_um.size else 1.0)
    mark = WORST_MARK if worst else ""
    loop = Panel(520, 300, f"{mark}{b.title}: loop", f"u_{axis} (V)", f"x_{axis} ({unit})")
    loop.line(b.u_v, b.x_um * factor, "measured", COLOURS[0], width=2.6)
    loop.line(b.u_v, b.x_model_um * factor, "model", COLOURS[1], width=1.0)
    residual = b.x_um - b.x_model_um
    rf, ru = ERROR_UNIT
    res = Panel(
        520,
        300,
        f"residual, held-out RMS {fmt_nm(b.held_out_rms_um)}",
        "time in the held-out cycles (ms)",
        f"measured − model ({ru})",
    )
    res.line(b.t_s * 1e3, residual * rf, "residual", COLOURS[3]).hline(0.0, "")
    return figure(
        [loop, res], f"{mark}{b.title} ({b.dataset_id}): loop and residual", frame="#C62828" if worst else None
    )


def history_figure(steps: list[dict], noise_floor_um: float | None) -> str:
    """Held-out RMS per lineage step on a log scale, like for like (every step on the last model's
    data, where the lineage has it), the noise-floor band and the 2× floor line."""
    rms = [s.get("like_for_like_rms_um") or s["validation_rms_um"] for s in steps]
    factor, unit = ERROR_UNIT
    panel = Panel(
        1040,
        320,
        "Error history: held-out RMS per step, every step on the same data",
        "lineage step (0: the first model)",
        f"held-out RMS ({unit}, log scale)",
        log_y=True,
        integer_x=True,
        legend="bottom-right",
    )
    if noise_floor_um:
        panel.band(0.0, noise_floor_um * factor, f"noise floor {fmt_nm(noise_floor_um)}")
        panel.hline(2 * noise_floor_um * factor, "2× noise floor")
    shown = [(i, v * factor, s["change"] or "first fit") for i, (s, v) in enumerate(zip(steps, rms)) if v]
    panel.points([p[0] for p in shown], [p[1] for p in shown], [p[2] for p in shown])
    return figure([panel], "error history: held-out RMS per lineage step with the noise floor")


def parameter_rows(params: dict, prefix: str = "") -> list[tuple[str, int, str]]:
    """(name, count, values as text) of every stored parameter, nested names joined by dots."""
    rows = []
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            rows += parameter_rows(value, name + ".")
            continue
        try:
            numbers = np.asarray(value, dtype=float).ravel()
        except (TypeError, ValueError):
            rows.append((name, 1, str(value)))
            continue
        rows.append((name, numbers.size, ", ".join(plain(v, 6) for v in numbers)))
    return rows


def _model_section(row: dict, description: dict, physical: dict) -> str:
    m = row["metrics"]
    labels = [
        [k, escape(str(v))]
        for k, v in (("name", row.get("name")), ("tags", ", ".join(row.get("tags") or [])), ("notes", row.get("notes")))
        if v
    ]
    facts = [
        ["model", f"<code>{escape(row['id'])}</code>"],
        *labels,
        ["kind", escape(row["kind"])],
        ["axis", escape(row["axis"].upper())],
        ["effects", escape(" + ".join(row["effects"]))],
        ["refined from", f"<code>{escape(row['parent_id'])}</code>" if row.get("parent_id") else "– (root)"],
        ["play operators", escape(operators_text(row))],
        ["training RMS", fmt_nm(m.get("train_rms_um"), 4)],
        ["held-out RMS", f'<span id="model-heldout">{fmt_nm(m.get("validation_rms_um"), 4)}</span>'],
        *without_lines_fact(m.get("without_lines")),
        ["held out", escape(str(m.get("held_out") or "the last ⌈20 %⌉ cycles of every block"))],
        ["created", escape(row["created_at"])],
        ["software", escape(row["software_version"])],
        ["parameters SHA-256", f"<code>{escape(row['parameters_sha256'])}</code>"],
    ]
    text = table_html(None, facts)
    words = [[escape(k), escape(v)] for k, v in description.items() if v]
    # not the fit's own figures (its training RMS on the decimated training rows): the metrics above give them
    params = {k: v for k, v in row["parameters"].items() if k not in ("model", "config") and not k.endswith("_rms_um")}
    values = [[f"<code>{escape(name)}</code>", str(n), escape(text)] for name, n, text in parameter_rows(params)]
    return (
        "<h2>1. Model</h2>"
        + text
        + "<h2>2. Fitted parameters</h2>"
        + physical_table(physical)
        + (table_html(["effect", "fitted, in words"], words) if words else "")
        # the stored values as the model keeps them (SI units, in their names) are folded: the table
        # above gives each physical figure once, in its display unit (a delay in µs, not also in s)
        + "<details><summary>Every stored parameter, as stored (SI units, in the names)</summary>"
        + table_html(["parameter (unit in the name)", "values", "fitted values"], values, {1}, ' id="parameters"')
        + "<p>As JSON (<code>model.to_dict()</code>):</p><pre>"
        + escape(json.dumps({"config": row["parameters"].get("config"), **params}))
        + "</pre></details>"
    )


def _datasets_section(datasets: list[dict], axis: str) -> str:
    rows = []
    for d in datasets:
        blocks = "; ".join(
            f"{b.get('index')}: {b.get('kind')}"
            + (f" {b['frequency_hz']:g} Hz × {b.get('cycles')}" if b.get("frequency_hz") else "")
            + (f" ({'+'.join(b['axes']).upper()})" if b.get("axes") else "")
            for b in d["blocks"]
        )
        label = " · ".join(x for x in (d.get("name"), ", ".join(d.get("tags") or []), d.get("notes")) if x)
        rows.append(
            [
                f"<code>{escape(d['id'])}</code>",
                escape(label),
                escape(d["source"]),
                escape(",".join(d["axes"]).upper()),
                str(d["samples"]),
                f"{d['sample_rate_hz']:g}",
                "partial: " + escape(d["partial_reason"] or "") if d.get("partial") else "complete",
                escape(blocks),
            ]
        )
    return (
        f"<h2>3. Data</h2><p>Axis {escape(axis.upper())} of these datasets; the last ⌈20 %⌉ cycles of every "
        "block are held out of the fit.</p>"
        + table_html(
            ["dataset", "name · tags · notes", "source", "axes", "samples", "rate (Hz)", "state", "blocks"],
            rows,
            {4, 5},
        )
    )


def _lineage_section(steps: list[dict], noise_floor_um: float | None) -> str:
    rows = [
        [
            str(i),
            f"<code>{escape(s['model_id'])}</code>",
            escape(s["change"] or "first fit"),
            escape(" + ".join(s["effects"])),
            f'<span class="rms-train">{fmt_nm(s["train_rms_um"], 4)}</span>',
            f'<span class="rms-heldout">{fmt_nm(s["validation_rms_um"], 4)}</span>',
            f'<span class="rms-like-for-like">{fmt_nm(s.get("like_for_like_rms_um"), 4)}</span>',
            value_text(s["validation_rms_um"] / noise_floor_um, 3)
            if noise_floor_um and s["validation_rms_um"]
            else "–",
        ]
        for i, s in enumerate(steps)
    ]
    return (
        "<h2>4. Lineage</h2><p>From the first model (step 0) to this one; each step is a stored model. Held-out RMS: on the "
        "data the step was fitted on; like for like: its effects on this model's datasets (refitted there where "
        "the step had fewer), so that every step is scored on the same held-out cycles.</p>"
        + table_html(
            [
                "step",
                "model",
                "change",
                "effects",
                "training RMS (mean of per-block)",
                "held-out RMS (the step's stored figure: mean of per-block held-out RMS)",
                "like for like (same held-out cycles)",
                "that held-out RMS / noise floor",
            ],
            rows,
            {0, 4, 5, 6, 7},
            ' id="lineage"',
        )
        + history_figure(steps, noise_floor_um)
    )


def _not_here(proposal: dict) -> str:
    """Why this bench runs no experiment for a proposal (its ``not_runnable_here``), or nothing."""
    why = proposal.get("not_runnable_here")
    return f' <span class="muted">This bench cannot run the experiment: {escape(why)}.</span>' if why else ""


def _experiment(body: dict, here: bool = True) -> str:
    """A sweep body: as the request to this service when this bench recorded the data, else as the plan
    to record on the stage that did (this bench cannot run another stage's experiments)."""
    if here:
        return f"<pre>POST /api/sweeps\n{escape(json.dumps(body))}</pre>"
    return f"<p class='muted'>To record on the stage that recorded the data, then import:</p><pre>{escape(json.dumps(body))}</pre>"


def _tested_words(c: dict) -> str:
    """A candidate's own test: the held-out RMS of its reference model, then with it (nm)."""
    if c.get("tested_rms_um") is None:
        return "–"
    return f"{fmt_nm(c.get('reference_rms_um'), 4)} → {fmt_nm(c.get('tested_rms_um'), 4)}"


def _diagnosis_section(d: dict) -> str:
    cands = [c for c in d.get("candidates") or [] if c.get("testable", True)]
    here = d.get("experiments_run_here") is not False
    rows = [
        [
            escape(c["effect"]),
            escape(c.get("kind") or ""),
            "yes" if c.get("claimed") else "no",
            value_text(c.get("score"), 3)
            + (" (capped)" if c.get("score_capped") else "")
            + (f"<br><small>{escape(c['score_of'])}</small>" if c.get("score_of") else ""),
            _tested_words(c),
            fmt_nm(c.get("expected_rms_um"), 4)
            if c.get("expected_rms_um") != d.get("residual_rms_um")
            else "not fitted",
            escape(c.get("evidence") or ""),
        ]
        for c in cands
    ]
    untestable = "".join(
        f"<li><b>{escape(c['effect'])}</b>: {escape(c.get('reason') or '')}"
        f"{_experiment(c['experiment'], here) if c.get('experiment') else _not_here(c)}</li>"
        for c in d.get("not_testable") or []
    )
    amb = d.get("ambiguity")
    return (
        "<h2>5. Diagnosis</h2>"
        f'<p class="verdict">Verdict: <span id="verdict" data-verdict="{escape(str(d.get("verdict")))}">'
        f"{escape(str(d.get('verdict')))}</span></p>"
        f'<p id="verdict-text">{escape(d.get("verdict_text") or "")}</p>'
        + (f'<p id="answer">{escape(d["answer"]["text"])}</p>' if d.get("answer") else "")
        + f"<p>Held-out RMS {fmt_nm(d.get('residual_rms_um'), 4)}"
        + (f" ({escape(d['residual_of'])})" if d.get("residual_of") else "")
        + " · noise floor "
        f'<span id="noise-floor">{fmt_nm(d.get("noise_floor_um"), 4)}</span>'
        + (
            f" · ratio {d['residual_rms_um'] / d['noise_floor_um']:.3g}"
            if d.get("residual_rms_um") and d.get("noise_floor_um")
            else ""
        )
        + "</p>"
        + (f"<p class='muted'>{escape(d['claim_rule'])}</p>" if d.get("claim_rule") else "")
        + "<h3>Candidate effects (claimed physical effects, then the others, then model capacity; each in "
        "score order, but the claimed physics by their size: the held-out mean square each removes over its claim's reference)</h3>"
        + "<p class='muted'>The score: the held-out mean square the effect's own test removes, as a share of this "
        "model's held-out mean square above the noise floor. Its test is a fit of its own (against its reference); "
        "'added to this model' is this model refitted with it, and only for a claimed effect or capacity.</p>"
        + table_html(
            [
                "effect",
                "kind",
                "claimed",
                "score",
                "its test: held-out RMS, reference → with it",
                "added to this model",
                "evidence",
            ],
            rows,
            {3, 4, 5},
            ' id="candidates"',
        )
        + (f'<h3>Not testable with this data</h3><ul id="not-testable">{untestable}</ul>' if untestable else "")
        + (
            '<p class="muted" id="not-tried">Not tried: '
            + "; ".join(f"<b>{escape(c['effect'])}</b> ({escape(c['reason'])})" for c in d["not_tried"])
            + ".</p>"
            if d.get("not_tried")
            else ""
        )
        + (
            f'<h3>Ambiguity</h3><p id="ambiguity">{escape(amb.get("text") or "")}</p>'
            + (_experiment(amb["experiment"], here) if amb.get("experiment") else _not_here(amb))
            if amb
            else ""
        )
    )


def _blocks_section(blocks: list[BlockCurves], axis: str, worst: int | None) -> str:
    figs = "".join(
        f'<div class="block-figure{" worst" if i == worst else ""}">{block_figure(b, axis, i == worst)}</div>'
        for i, b in enumerate(blocks)
    )
    return (
        "<h2>6. Measured against model, block by block</h2><p>Each block's held-out cycles (never fitted): "
        f"the loop, measured and predicted, and the residual; at most {MAX_CURVE_POINTS} points per curve. "
        "The block with the largest held-out RMS (printed in its title) is framed in red.</p>" + figs
    )


def _reproduce_section(commands: dict[str, str]) -> str:
    parts = [("curl", "REST (curl)"), ("cli", "evcbench CLI"), ("python", "Python client")]
    return (
        "<h2>7. Reproduce</h2><p>The requests that record the datasets again (their stored plans) and fit the "
        "lineage step by step on the new ids. On another bench, or a later day, the figures differ by the "
        "bench's noise and drift.</p>"
        + "".join(f'<h3>{title}</h3><pre id="reproduce-{key}">{escape(commands[key])}</pre>' for key, title in parts)
    )


def render_report(
    model_row: dict,
    description: dict,
    datasets: list[dict],
    steps: list[dict],
    diagnosis: dict,
    blocks: list[BlockCurves],
    commands: dict[str, str],
    generated_at: str,
    worst: int | None = None,
    physical: dict | None = None,
) -> str:
    """The whole report as HTML text; ``worst``: the index in ``blocks`` of the block with the largest
    held-out RMS (marked); ``physical``: the model's physical parameters ``{effect: {name: (value, unit)}}``."""
    title = f"Model {model_row['id']}: {model_row['kind']}, axis {model_row['axis'].upper()}"
    return (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        f"<title>{escape(title)}</title><style>{CSS}</style></head><body>"
        f'<h1>{escape(title)}</h1><p class="muted">{escape(" + ".join(model_row["effects"]))} · '
        f"EVC Bench report generated {escape(generated_at)}</p>"
        + _model_section(model_row, description, physical or {})
        + _datasets_section(datasets, model_row["axis"])
        + _lineage_section(steps, diagnosis.get("noise_floor_um"))
        + _diagnosis_section(diagnosis)
        + _blocks_section(blocks, model_row["axis"], worst)
        + _reproduce_section(commands)
        + f"<footer><p>{escape(PDF_NOTE)}</p></footer></body></html>"
    )
