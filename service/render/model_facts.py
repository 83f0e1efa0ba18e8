"""The report's facts about a stored model beyond its figures: its effects' parameters with their roles,
its play operators, and its held-out RMS with the lines seen at rest taken out (HTML text; nm in the
words, the values as stored)."""

from __future__ import annotations

from html import escape

from service.science.data.units import fmt_nm, plain
from service.science.effects import EFFECTS


def table_html(head: list[str] | None, rows: list[list[str]], numeric=frozenset(), attrs: str = "") -> str:
    """An HTML table (``head`` None: no header row); cells are already-escaped HTML; columns in
    ``numeric`` right-aligned."""
    cls = lambda i: ' class="num"' if i in numeric else ""  # noqa: E731
    out = [
        f"<table{attrs}>"
        + ("<tr>" + "".join(f"<th{cls(i)}>{h}</th>" for i, h in enumerate(head)) + "</tr>" if head else "")
    ]
    out += ["<tr>" + "".join(f"<td{cls(i)}>{c}</td>" for i, c in enumerate(r)) + "</tr>" for r in rows]
    return "".join(out) + "</table>"


def value_text(value, digits: int = 4) -> str:
    """A stored value to ``digits`` significant figures ("–" for None)."""
    return "–" if value is None else plain(value, digits)


def physical_table(physical: dict) -> str:
    """The stored model's effect parameters (``{effect: {"role", "values": {name: (value, unit)}}}``), each
    with its unit and the effect's role, as Discover's "Effects found" and the Lab page print them; ""
    when it has none (a paper's PI)."""
    rows = [
        [
            escape(effect),
            escape(ROLE_WORDS.get(entry["role"], entry["role"])),
            f"<code>{escape(name)}</code>",
            f'<span data-parameter="{escape(effect)}.{escape(name)}" data-value="{value!r}">{value_text(value)}</span>'
            + (f" {escape(unit)}" if unit and unit != "1" else ""),
        ]
        for effect, entry in physical.items()
        for name, (value, unit) in entry["values"].items()
    ]
    head = ["effect", "as", "parameter", "value (the stored model's)"]
    return table_html(head, rows, {3}, ' id="physical-parameters"') if rows else ""


#: an effect's role in the model, in the report's words
ROLE_WORDS = {
    "physical": "physics",
    "capacity": "model capacity, not physics (on a base that draws any loop shape, a loop-shape effect's weights are that base's shape)",
}


def operators_text(row: dict) -> str:
    """The model's play operators as its parameters hold them, and the count asked for where a capacity
    effect multiplied it ("20 (10 asked; operators doubles them)")."""
    asked = (row.get("options") or {}).get("n_operators")
    held = len(row["parameters"].get("thresholds_v") or ())
    if not held or asked is None or held == asked:
        return str(asked if asked is not None else held or "–")
    why = [e for e in row["effects"] if e in EFFECTS and EFFECTS[e].operator_factor > 1]
    return f"{held} ({asked} asked; {' and '.join(why) or 'the model'} multiplies them)"


def without_lines_fact(w: dict | None) -> list[list[str]]:
    """The held-out RMS with the lines seen at rest taken out, as a fact row, where there were lines."""
    if not w:
        return []
    lines = ", ".join(f"{f:.4g} Hz" for f in w["lines_hz"])
    return [
        [
            f"held-out RMS, the {lines} line{'s' if len(w['lines_hz']) > 1 else ''} seen at rest taken out "
            "(the records the diagnosis and discover judge on)",
            f'<span id="model-heldout-without-lines">{fmt_nm(w["validation_rms_um"], 4)}</span>',
        ]
    ]
