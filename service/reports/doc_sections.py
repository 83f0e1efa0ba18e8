"""Sections of a generated doc that another report writes: delimited by HTML comments, replaced in
place by their own writer and kept by the doc's writer when it rewrites the rest."""

from __future__ import annotations

import re
from pathlib import Path


def markers(name: str) -> tuple[str, str]:
    """The begin and end comments of section ``name``."""
    return f"<!-- {name}: begin -->", f"<!-- {name}: end -->"


def _pattern(name: str) -> re.Pattern:
    begin, end = markers(name)
    return re.compile(re.escape(begin) + r".*?" + re.escape(end) + r"\n?", re.S)


def wrap(name: str, body: str) -> str:
    """``body`` between section ``name``'s markers."""
    begin, end = markers(name)
    return f"{begin}\n{body.rstrip()}\n\n{end}\n"


def with_section(text: str, name: str, block: str) -> str:
    """``text`` with section ``name`` replaced by ``block`` (a ``wrap``), appended when it has none."""
    pattern = _pattern(name)
    if pattern.search(text):
        return pattern.sub(lambda _: block, text)
    return text.rstrip("\n") + "\n\n" + block


def kept_section(path: Path, name: str) -> str:
    """Section ``name`` of the file at ``path`` with its markers ("" when there is none)."""
    if not Path(path).exists():
        return ""
    found = _pattern(name).search(Path(path).read_text())
    return found.group(0) if found else ""


def write_section(path: Path, name: str, body: str) -> None:
    """Replace (or append) section ``name`` of the file at ``path`` with ``body``."""
    path = Path(path)
    path.write_text(with_section(path.read_text() if path.exists() else "", name, wrap(name, body)))
