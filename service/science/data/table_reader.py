"""Reading an uploaded table as a stream: its layout (header row, delimiter, width) from the first
line, then the numbers of the columns asked for, ``READ_BLOCK_BYTES`` of text at a time, parsed by
numpy's C parser into arrays that grow in place. A block the fast parser refuses is read again
line by line, for a message naming the file's line. No HTTP, no store.

Lines are split at ``\\n`` (``\\r\\n`` and old-Mac ``\\r`` files too); blank lines and lines starting
with ``#`` are skipped; fields are trimmed; columns that are not asked for are never converted.
"""
from __future__ import annotations

import io
from dataclasses import dataclass
from typing import BinaryIO, Iterator

import numpy as np

from service.science.errors import FieldError

#: text parsed per step: about 900 rows of a typical 5-column table, ~1 ms of numpy's parser, which
#: holds the interpreter lock throughout (64 KiB held it 8 ms, and the emergency stop's thread waited)
READ_BLOCK_BYTES = 8 * 1024
#: a line longer than this is not a table row
MAX_LINE_BYTES = 1024 * 1024
DELIMITERS = {"comma": ",", ",": ",", "tab": "\t", "\\t": "\t", "\t": "\t", "semicolon": ";", ";": ";",
              "whitespace": None, "space": None}


class DataError(FieldError):
    """An uploaded table is malformed or out of range; ``field`` names the field or column."""


@dataclass
class Layout:
    """``header`` (lower-case names, or None), ``sep`` (None: runs of whitespace), ``width`` (fields),
    ``written`` (the header's names as the file spells them, for messages)."""

    header: list[str] | None
    sep: str | None
    width: int
    written: list[str] | None = None


class TableReader:
    """One pass over a binary file object: ``layout`` is known on construction (from the first
    line that is neither blank nor a comment); ``columns(indices)`` then reads the data rows."""

    def __init__(self, handle: BinaryIO, delimiter: str | None = None):
        if delimiter not in (None, "", "auto") and delimiter not in DELIMITERS:
            raise DataError("delimiter", f"unknown delimiter {delimiter!r}; use comma, tab, semicolon or whitespace")
        self._handle = handle
        self._size_bytes = _remaining_bytes(handle)
        self._newline: bytes | None = None
        self._line_no = 1          # number (1-based) of the first line not yet handed out
        self._blocks = self._text_blocks()
        self._first: tuple[int, list[str]] | None = None
        self.layout = self._sniff(delimiter)

    # ------------------------------------------------------------------ layout
    def _sniff(self, delimiter: str | None) -> Layout:
        for first_no, lines in self._blocks:
            for k, line in enumerate(lines):
                text = line.strip()
                if not text or text.startswith("#"):
                    continue
                sep = DELIMITERS[delimiter] if delimiter not in (None, "", "auto") else ("," if "," in text else None)
                fields = _split(text, sep)
                if all(_is_number(f) for f in fields):
                    self._first = (first_no + k, lines[k:])
                    return Layout(None, sep, len(fields))
                self._first = (first_no + k + 1, lines[k + 1:])
                names = [f.strip('"') for f in fields]
                return Layout([n.lower() for n in names], sep, len(fields), names)
        raise DataError("file", "is empty")

    # ------------------------------------------------------------------ rows
    def columns(self, indices: list[int]) -> tuple[dict[int, np.ndarray], int]:
        """``({index: values}, rows)``: the columns ``indices`` (0-based) of every data row."""
        wanted = sorted(set(indices))
        grown = {i: _Growing(self._estimate_rows()) for i in wanted}
        rows = 0
        for first_no, lines in self._data_blocks():
            values = self._parse(lines, first_no, wanted)
            for j, i in enumerate(wanted):
                grown[i].extend(values[:, j])
            rows += values.shape[0]
        return {i: g.array() for i, g in grown.items()}, rows

    def _data_blocks(self) -> Iterator[tuple[int, list[str]]]:
        if self._first is not None:
            yield self._first
            self._first = None
        yield from self._blocks

    def _parse(self, lines: list[str], first_no: int, usecols: list[int]) -> np.ndarray:
        """(rows, len(usecols)) floats of one block; a DataError naming the line if one is malformed.

        Every column at once when they are all numbers (numpy checks that each row has as many);
        else the rows' field counts are checked here and only the columns asked for are converted."""
        sep, width = self.layout.sep, self.layout.width
        if not "".join(lines).strip():
            return np.empty((0, len(usecols)))
        try:
            rows = np.loadtxt(lines, delimiter=sep, comments="#", ndmin=2, dtype=float)
            if rows.shape[1] == width:
                return rows[:, usecols]
        except ValueError:
            pass   # text or blanks in some column, spaces on a blank line, or a real error
        kept = self._checked_lines(lines, first_no)
        if not kept:
            return np.empty((0, len(usecols)))
        try:
            return np.loadtxt(kept, delimiter=sep, comments="#", ndmin=2, usecols=usecols, dtype=float)
        except ValueError:
            pass   # a value that is not a number: find it, for the message
        for k, line in enumerate(lines):
            text = line.strip()
            if text and not text.startswith("#"):
                fields = _split(text, sep)
                bad = [fields[i] for i in usecols if not _is_number(fields[i])]
                if bad:
                    raise DataError("file", f"line {first_no + k}: {bad[0]!r} is not a number")
        return np.array([[float(_split(t, sep)[i]) for i in usecols] for t in kept]).reshape(-1, len(usecols))

    def _checked_lines(self, lines: list[str], first_no: int) -> list[str]:
        """The data lines of a block (blank and comment lines dropped), each checked to have as many
        fields as the first line."""
        sep, width = self.layout.sep, self.layout.width
        kept = []
        for k, line in enumerate(lines):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            count = len(text.split()) if sep is None else text.count(sep) + 1
            if count != width:
                raise DataError("file", f"line {first_no + k} has {count} fields; expected {width}")
            kept.append(text)
        return kept

    # ------------------------------------------------------------------ text
    def _text_blocks(self) -> Iterator[tuple[int, list[str]]]:
        """(number of the first line, lines) per block of whole lines, decoded as UTF-8."""
        pending = b""
        first = True
        while True:
            chunk = self._handle.read(READ_BLOCK_BYTES)
            if self._newline is None and chunk:
                self._newline = b"\n" if b"\n" in chunk or b"\r" not in chunk else b"\r"
            data = pending + chunk
            cut = data.rfind(self._newline) + 1 if chunk else len(data)
            if cut == 0 and len(data) > MAX_LINE_BYTES:
                raise DataError("file", f"line {self._line_no} is longer than {MAX_LINE_BYTES // 1024} KiB; "
                                         "is this a table?")
            whole, pending = data[:cut], data[cut:]
            if whole:
                try:
                    text = whole.decode("utf-8-sig" if first else "utf-8")
                except UnicodeDecodeError:
                    raise DataError("file", "is not UTF-8 text") from None
                first = False
                lines = text.split(self._newline.decode())
                if lines[-1] == "":
                    lines.pop()
                yield self._line_no, lines
                self._line_no += len(lines)
            if not chunk:
                return

    def _estimate_rows(self) -> int:
        """Rows the rest of the file probably holds (from the first block's line length)."""
        if self._first is None or not self._first[1]:
            return 1024
        lines = self._first[1]
        per_line = max(1.0, sum(len(s) + 1 for s in lines) / len(lines))
        return int(1.05 * self._size_bytes / per_line) + 1024


class _Growing:
    """A float array filled block by block, grown in place (1.5×) when full."""

    def __init__(self, capacity: int):
        self._data = np.empty(max(capacity, 16))
        self._n = 0

    def extend(self, values: np.ndarray) -> None:
        need = self._n + values.size
        if need > self._data.size:
            self._data.resize(max(need, int(1.5 * self._data.size)), refcheck=False)
        self._data[self._n:need] = values
        self._n = need

    def array(self) -> np.ndarray:
        self._data.resize(self._n, refcheck=False)
        return self._data


def _split(text: str, sep: str | None) -> list[str]:
    return text.split() if sep is None else [f.strip() for f in text.split(sep)]


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def _remaining_bytes(handle: BinaryIO) -> int:
    """Bytes from the current position to the end (0 if the object cannot seek)."""
    try:
        here = handle.tell()
        end = handle.seek(0, io.SEEK_END)
        handle.seek(here)
        return max(end - here, 0)
    except (OSError, AttributeError, ValueError):
        return 0
