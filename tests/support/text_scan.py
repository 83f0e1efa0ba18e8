"""What the user reads, scanned (issue 39): one unit per quantity, and no part larger than its whole.

The unit table: errors and noise in nm (their mean squares in nm²), delays and lags in µs,
frequencies in Hz, no figure with a unit in exponent notation (4.11e-05 ms). Lengths in µm are
positions and spans (a gauge range, a drive's stroke), never an error: the texts scanned here (the
diagnosis, discover, the report's diagnosis and lineage) hold only errors and noise, so any µm there
is an error in the wrong unit. A p-value may keep its exponent: it has no unit.
"""

from __future__ import annotations

import re

NUMBER = r"[-−]?\d+(?:[.,]\d+)*(?:[eE][+-]?\d+)?"
#: a figure and the unit written after it
QUANTITY = re.compile(
    rf"(?P<value>{NUMBER})\s*(?P<unit>nm²|nm|µm|μm|um|mm|ms|µs|μs|us|ns|kHz|mHz|Hz)\b(?P<rest>[·/]\S*)?"
)
#: units that must not appear in these texts for their quantity (errors → nm, delays → µs)
WRONG_UNITS = {
    "µm": "an error in µm",
    "μm": "an error in µm",
    "um": "an error in um",
    "mm": "an error in mm",
    "ms": "a delay in ms",
    "ns": "a delay in ns",
    "kHz": "a frequency in kHz",
    "mHz": "a frequency in mHz",
}
#: a compound unit with one of the wrong units in it (µm·ms/V)
WRONG_COMPOUND = re.compile(r"(?:µm|μm|\bms\b)[·/]|[·/](?:µm|μm|ms)\b")
#: "A nm of (their|the remaining|…) B nm": a part stated of a whole
PART_OF = re.compile(
    rf"(?P<part>{NUMBER}) (?P<u1>nm²|nm) of (?:the reference's |the |their |its |this model's )?(?:remaining |held-out |unseen )?"
    rf"(?P<whole>{NUMBER}) (?P<u2>nm²|nm)"
)
#: "A nm² (of held-out mean square) removed by its test (…) / B nm² (…) above the noise floor": a score's
#: numerator over its denominator, a part of its whole
REMOVED_OVER = re.compile(
    rf"(?P<part>{NUMBER}) (?P<u1>nm²|nm) (?:of held-out mean square )?removed by (?:its test|adding it)[^/;]*? / "
    rf"(?P<whole>{NUMBER}) (?P<u2>nm²|nm)"
)
#: "N % of …": a share
PERCENT_OF = re.compile(rf"(?P<pct>{NUMBER}) ?% of the")
#: "−A nm² (of held-out mean square) removed": a negative amount stated as a removal (it is a rise)
NEGATIVE_REMOVED = re.compile(r"[-−]\d+(?:[.,]\d+)* ?(?:nm²|nm|%)(?: of [^.;:/()]*?)? remov(?:ed|es)\b")


def _number(text: str) -> float:
    return float(text.replace("−", "-").replace(",", ""))


def unit_problems(text: str) -> list[str]:
    """Each figure in ``text`` whose unit breaks the table, with its context."""
    out = []
    for m in QUANTITY.finditer(text):
        context = text[max(0, m.start() - 60) : m.end() + 20]
        if "e" in m["value"].lower():
            out.append(f"exponent notation {m.group(0)!r}: …{context}…")
        if m["unit"] in WRONG_UNITS:
            out.append(f"{WRONG_UNITS[m['unit']]} {m.group(0)!r}: …{context}…")
    for m in WRONG_COMPOUND.finditer(text):
        out.append(f"compound unit {m.group(0)!r}: …{text[max(0, m.start() - 60) : m.end() + 20]}…")
    return out


def part_whole_problems(text: str) -> list[str]:
    """Each "A nm of B nm" or "A nm² removed by its test … / B nm²" with A > B (at the printed digits),
    each share outside 0–100 % and each negative amount "removed" (a rise)."""
    out = []
    for m in (*PART_OF.finditer(text), *REMOVED_OVER.finditer(text)):
        if m["u1"] == m["u2"] and _number(m["part"]) > _number(m["whole"]):
            out.append(f"part > whole: …{text[max(0, m.start() - 80) : m.end() + 40]}…")
    for m in PERCENT_OF.finditer(text):
        if not 0.0 <= _number(m["pct"]) <= 100.0:
            out.append(f"share outside 0–100 %: …{text[max(0, m.start() - 80) : m.end() + 40]}…")
    for m in NEGATIVE_REMOVED.finditer(text):
        out.append(f"a negative amount removed: …{text[max(0, m.start() - 80) : m.end() + 40]}…")
    return out


#: a clause whose content is missing: a colon, dash or "of" followed by nothing before the stop
EMPTY_CLAUSE = re.compile(r"(?::|—|\bof)\s*[.;,)]|\(\s*\)|\s\.\s|^\s*[.;,]")


def empty_clauses(text: str) -> list[str]:
    """Clauses with nothing in them ("before any fit: ." was one), each with its surroundings."""
    return [f"empty clause in {text[max(m.start() - 40, 0) : m.end() + 10]!r}" for m in EMPTY_CLAUSE.finditer(text)]


def texts_of(value, path: str = "") -> list[tuple[str, str]]:
    """(path, text) of every string in a JSON value, except ids, figures' arrays and experiment bodies
    (ready-to-POST JSON, not words)."""
    if isinstance(value, dict):
        return [
            pair
            for k, v in value.items()
            if k not in ("figure", "experiment", "id", "parameters_sha256")
            for pair in texts_of(v, f"{path}.{k}")
        ]
    if isinstance(value, list):
        return [pair for i, v in enumerate(value) for pair in texts_of(v, f"{path}[{i}]")]
    return [(path, value)] if isinstance(value, str) else []


def scan(value, check) -> list[str]:
    """``check`` (unit_problems or part_whole_problems) over every text of a JSON value, with its path."""
    return [f"{path}: {problem}" for path, text in texts_of(value) for problem in check(text)]


def repeated_part_within_whole(d: dict) -> list[str]:
    """A diagnosis's stored figures: the repeatable part within the repeated cycles' RMS, the shares
    within 0–1."""
    out = []
    rep, whole = d.get("repeatable_rms_um"), d.get("repeated_cycles_rms_um")
    if rep is not None and (whole is None or rep > whole):
        out.append(f"repeatable {rep} µm of a whole {whole} µm")
    for c in d.get("candidates") or []:
        if not 0.0 <= c.get("score", 0.0) <= 1.0 or c.get("excess_removed", 0.0) > 1.0:
            out.append(f"{c['effect']}: score {c.get('score')}, excess removed {c.get('excess_removed')}")
    remainder = d.get("remainder") or {}
    for s in remainder.get("signatures") or []:
        if not 0.0 <= s["share_of_excess"] <= 1.0:
            out.append(f"remainder {s['signature']}: share {s['share_of_excess']}")
    total = sum(s["share_of_excess"] for s in remainder.get("signatures") or [])
    if total > 1.0 and not (remainder.get("shares_overlap") and "overlap" in remainder.get("shares_text", "")):
        out.append(f"remainder shares of one whole sum to {100 * total:.1f} %, not labelled as overlapping")
    return out
