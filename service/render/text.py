"""User text as it is printed in one line: a name in a list, a script comment, a header."""

from __future__ import annotations

#: besides the C0 and C1 control characters, the two Unicode separators that end a line
LINE_SEPARATORS = "\u2028\u2029"


def breaks_a_line(character: str) -> bool:
    """Whether ``character`` is a control character or a line separator (it may end a printed line)."""
    code = ord(character)
    return code < 32 or 0x7F <= code < 0xA0 or character in LINE_SEPARATORS


def one_line_text(text) -> str:
    """``text`` with every control character and line separator shown as a space."""
    return "".join(" " if breaks_a_line(c) else c for c in str(text))


def step_change(step: dict) -> str | None:
    """What a discover step changed, in words: "+creep", "hysterons_fine in place of hysterons" (the
    base's grid swapped at the loop's end), or None (the start, or a refit on an experiment's data)."""
    if step.get("replaced"):
        return f"{step['added']} in place of {step['replaced']}"
    return f"+{step['added']}" if step.get("added") else None
