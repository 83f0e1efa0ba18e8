"""Reading an uploaded table as a stream: its layout (header row, delimiter, width) from the first
line, then the numbers of the columns asked for, ``READ_BLOCK_BYTES`` of text at a time, parsed by
numpy's C parser into arrays that grow in place. A block the fast parser refuses is read again
line by line, for a message naming the file's line. No HTTP, no store.

Other labs' exports are read as they come: lines split at ``\\n`` (``\\r\\n`` and old-Mac ``\\r``
files too); UTF-8 (with or without a BOM), UTF-16 with its BOM, or else Latin-1 (a ``µm`` written by
an old Windows program); blank lines, lines of empty fields (a spreadsheet's trailing ``,,``) and
comment lines starting with ``#`` or ``%`` (MATLAB, Octave) are skipped; fields are trimmed and may be
quoted; a semicolon delimiter is guessed from the first line, and then decimal commas
(``0,125;1,5``) are read as decimal points; a row of units under the header (``s, V, um``) is kept
as the columns' units; a header of the column numbers alone (``0,1,2``, as pandas writes it) is a
header. Columns that are not asked for are never converted.
"""

from __future__ import annotations

import codecs
import io
from collections.abc import Iterator
from dataclasses import dataclass
from typing import BinaryIO

import numpy as np

from service.science.errors import FieldError

#: text parsed per step: about 900 rows of a typical 5-column table, ~1 ms of numpy's parser, which
#: holds the interpreter lock throughout (64 KiB held it 8 ms, and the emergency stop's thread waited)
READ_BLOCK_BYTES = 8 * 1024
#: a line longer than this is not a table row
MAX_LINE_BYTES = 1024 * 1024
DELIMITERS = {
    "comma": ",",
    ",": ",",
    "tab": "\t",
    "\\t": "\t",
    "\t": "\t",
    "semicolon": ";",
    ";": ";",
    "whitespace": None,
    "space": None,
}


class DataError(FieldError):
    """An uploaded table is malformed or out of range; ``field`` names the field or column."""


#: a line starting with one of these is a comment
COMMENTS = ("#", "%")


@dataclass
class Layout:
    """``header`` (lower-case names, or None), ``sep`` (None: runs of whitespace), ``width`` (fields),
    ``written`` (the header's names as the file spells them, for messages), ``units`` (a units row
    under the header, as written, or None), ``decimal_comma`` (numbers written ``0,5``)."""

    header: list[str] | None
    sep: str | None
    width: int
    written: list[str] | None = None
    units: list[str] | None = None
    decimal_comma: bool = False


class TableReader:
    """One pass over a binary file object: ``layout`` is known on construction (from the first
    line that is neither blank nor a comment); ``columns(indices)`` then reads the data rows."""

    def __init__(self, handle: BinaryIO, delimiter: str | None = None):
        if delimiter not in (None, "", "auto") and delimiter not in DELIMITERS:
            raise DataError("delimiter", f"unknown delimiter {delimiter!r}; use comma, tab, semicolon or whitespace")
        self._handle = handle
        self._size_bytes = _remaining_bytes(handle)
        self._newline: str | None = None
        self._line_no = 1  # number (1-based) of the first line not yet handed out
        self.encoding = "utf-8"  #: the encoding the text was read in (utf-16 by its BOM, latin-1 if not UTF-8)
        self._blocks = self._text_blocks()
        self._first: list[tuple[int, list[str]]] = []  # blocks read ahead by the layout's sniff
        self.layout = self._sniff(delimiter)

    # ------------------------------------------------------------------ layout
    def _sniff(self, delimiter: str | None) -> Layout:
        """The layout from the first lines that are neither blank nor comments: a header (and a
        units row under it), or the first data row; the first data row says whether the numbers
        are written with decimal commas."""
        lines = self._meaningful_lines(3)
        if not lines:
            raise DataError("file", "is empty")
        (first_no, text), following = lines[0], lines[1:]
        sep = DELIMITERS[delimiter] if delimiter not in (None, "", "auto") else _guess_delimiter(text)
        fields = _split(text, sep)
        next_fields = _split(following[0][1], sep) if following else None
        if _numbers(fields, sep) is None and sep is None and "\t" in text:  # names with spaces, between tabs
            fields = [f.strip() for f in text.split("\t")]
            next_fields = [f.strip() for f in following[0][1].split("\t")] if following else None
        if _numbers(fields, sep) is not None and not _column_numbers(fields, next_fields, sep):
            self._rewind_to(first_no)
            return Layout(None, sep, len(fields), decimal_comma=_numbers(fields, sep))
        names = [f.strip('"') for f in fields]
        units = None
        if (
            next_fields is not None
            and len(next_fields) == len(fields)
            and not any(_is_number(f) or _is_number(f.replace(",", ".")) for f in next_fields)
        ):
            units = [f.strip('"') for f in next_fields]  # a units row under the header
            self._rewind_to(following[0][0] + 1)
        else:
            self._rewind_to(first_no + 1)
        data_line = (following[1:] if units is not None else following)[:1]
        data_fields = _split(data_line[0][1], sep) if data_line else None
        decimal_comma = bool(data_fields is not None and _numbers(data_fields, sep))
        return Layout([n.lower() for n in names], sep, len(fields), names, units, decimal_comma)

    def _meaningful_lines(self, count: int) -> list[tuple[int, str]]:
        """Up to ``count`` (line number, stripped text) of the first lines that hold something,
        reading blocks ahead (kept for ``columns``)."""
        found: list[tuple[int, str]] = []
        for first_no, lines in self._blocks:
            self._first.append((first_no, lines))
            for k, line in enumerate(lines):
                if not _is_blank(line, None):
                    found.append((first_no + k, line.strip()))
                    if len(found) == count:
                        return found
        return found

    def _rewind_to(self, line_no: int) -> None:
        """Keep the read-ahead lines from ``line_no`` on as the first data lines."""
        kept = []
        for first_no, lines in self._first:
            skip = max(0, min(len(lines), line_no - first_no))
            if skip < len(lines):
                kept.append((first_no + skip, lines[skip:]))
        self._first = kept

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
        while self._first:
            yield self._first.pop(0)
        yield from self._blocks

    def _parse(self, lines: list[str], first_no: int, usecols: list[int]) -> np.ndarray:
        """(rows, len(usecols)) floats of one block; a DataError naming the line if one is malformed.

        Every column at once when they are all numbers (numpy checks that each row has as many);
        else the rows' field counts are checked here and only the columns asked for are converted."""
        sep, width = self.layout.sep, self.layout.width
        if not "".join(lines).strip():
            return np.empty((0, len(usecols)))
        if self.layout.decimal_comma:
            lines = [line.replace(",", ".") for line in lines]
        try:
            rows = np.loadtxt(lines, delimiter=sep, comments=COMMENTS, quotechar='"', ndmin=2, dtype=float)
            if rows.shape[1] == width:
                return rows[:, usecols]
        except ValueError:
            pass  # text or blanks in some column, spaces on a blank line, or a real error
        kept = self._checked_lines(lines, first_no)
        if not kept:
            return np.empty((0, len(usecols)))
        try:
            return np.loadtxt(
                kept, delimiter=sep, comments=COMMENTS, quotechar='"', ndmin=2, usecols=usecols, dtype=float
            )
        except ValueError:
            pass  # a value that is not a number: find it, for the message
        for k, line in enumerate(lines):
            if not _is_blank(line, sep):
                fields = _split(line.strip(), sep)
                bad = [i for i in usecols if not _is_number(fields[i])]
                if bad:
                    column = self.layout.written[bad[0]] if self.layout.written else bad[0]
                    what = "is empty" if not fields[bad[0]] else f"{fields[bad[0]]!r} is not a number"
                    raise DataError("file", f"line {first_no + k}, column {column!r}: {what}")
        return np.array([[_number(_split(t, sep)[i]) for i in usecols] for t in kept]).reshape(-1, len(usecols))

    def _checked_lines(self, lines: list[str], first_no: int) -> list[str]:
        """The data lines of a block (blank and comment lines dropped), each checked to have as many
        fields as the first line."""
        sep, width = self.layout.sep, self.layout.width
        kept = []
        for k, line in enumerate(lines):
            if _is_blank(line, sep):
                continue
            text = line.strip()
            count = len(text.split()) if sep is None else text.count(sep) + 1
            if count != width:
                raise DataError("file", f"line {first_no + k} has {count} fields; expected {width}")
            kept.append(text)
        return kept

    # ------------------------------------------------------------------ text
    def _text_blocks(self) -> Iterator[tuple[int, list[str]]]:
        """(number of the first line, lines) per block of whole lines, decoded as the file's start
        says (``_decoder_for``); a UTF-8 file that turns out not to be is read on as Latin-1."""
        decoder, pending = None, ""
        while True:
            chunk = self._handle.read(READ_BLOCK_BYTES)
            if decoder is None:
                decoder = _decoder_for(chunk)
                self.encoding = decoder.encoding.replace("-sig", "")
            try:
                text = pending + decoder.decode(chunk, final=not chunk)
            except UnicodeDecodeError:
                if not decoder.encoding.startswith("utf-8"):
                    raise DataError(
                        "file", f"is not valid {decoder.encoding.upper()} text (near line {self._line_no})"
                    ) from None
                buffered = decoder.getstate()[0]  # bytes of a character the chunk ended inside
                decoder = _Decoder("latin-1")
                self.encoding = "latin-1"
                text = pending + decoder.decode(buffered + chunk, final=not chunk)
            if self._newline is None and text:
                self._newline = "\n" if "\n" in text or "\r" not in text else "\r"
            cut = text.rfind(self._newline or "\n") + 1 if chunk else len(text)
            if cut == 0 and len(text) > MAX_LINE_BYTES:
                raise DataError(
                    "file", f"line {self._line_no} is longer than {MAX_LINE_BYTES // 1024} KiB; is this a table?"
                )
            whole, pending = text[:cut], text[cut:]
            if whole:
                lines = whole.split(self._newline or "\n")
                if lines[-1] == "":
                    lines.pop()
                yield self._line_no, lines
                self._line_no += len(lines)
            if not chunk:
                return

    def _estimate_rows(self) -> int:
        """Rows the rest of the file probably holds (from the first block's line length)."""
        if not self._first or not self._first[0][1]:
            return 1024
        lines = self._first[0][1]
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
        self._data[self._n : need] = values
        self._n = need

    def array(self) -> np.ndarray:
        self._data.resize(self._n, refcheck=False)
        return self._data


class _Decoder:
    """An incremental decoder that knows its encoding's name (for messages)."""

    def __init__(self, encoding: str):
        self.encoding = encoding
        self._decoder = codecs.getincrementaldecoder(encoding)()

    def decode(self, data: bytes, final: bool = False) -> str:
        return self._decoder.decode(data, final)

    def getstate(self):
        return self._decoder.getstate()


def _decoder_for(start: bytes) -> _Decoder:
    """UTF-16 (its BOM, as a spreadsheet's "Unicode text" starts), UTF-8 with or without a BOM
    (Latin-1 if it turns out not to be); a start with NUL bytes and no BOM is not text."""
    if start.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        return _Decoder("utf-16")
    if b"\x00" in start:
        raise DataError("file", "is binary, not a text table (a spreadsheet such as .xlsx? export it as CSV)")
    return _Decoder("utf-8-sig")


def _guess_delimiter(text: str) -> str | None:
    """The delimiter of a first line: a semicolon if there is one (it is never a decimal mark: such
    files write ``0,5``), else runs of whitespace if it has a tab (a tab-separated export, perhaps with
    decimal commas), else a comma if it has one, else runs of whitespace."""
    return ";" if ";" in text else None if "\t" in text else "," if "," in text else None


def _split(text: str, sep: str | None) -> list[str]:
    return text.split() if sep is None else [f.strip() for f in text.split(sep)]


def _is_blank(line: str, sep: str | None) -> bool:
    """A line that holds no value: empty, a comment, or only delimiters (a spreadsheet's ``,,,``)."""
    text = line.strip()
    return not text or text.startswith(COMMENTS) or (sep is not None and not text.replace(sep, "").strip())


def _number(text: str) -> float:
    return float(text.strip().strip('"'))


def _is_number(text: str) -> bool:
    try:
        _number(text)
        return True
    except ValueError:
        return False


def _numbers(fields: list[str], sep: str | None) -> bool | None:
    """Whether ``fields`` are all numbers: False if as written, True if with decimal commas (when the
    delimiter is not a comma), None if they are not."""
    if all(_is_number(f) for f in fields):
        return False
    if sep != "," and all(_is_number(f.replace(",", ".")) for f in fields):
        return True
    return None


def _column_numbers(fields: list[str], next_fields: list[str] | None, sep: str | None) -> bool:
    """A header of the columns' numbers, 0, 1, 2, … (pandas' to_csv of an unnamed frame), above rows
    of decimals: not a first row of data."""
    return (
        len(fields) >= 2
        and [f.strip('"') for f in fields] == [str(i) for i in range(len(fields))]
        and next_fields is not None
        and _numbers(next_fields, sep) is not None
        and not all(f.strip('"').lstrip("+-").isdigit() for f in next_fields)
    )


def _remaining_bytes(handle: BinaryIO) -> int:
    """Bytes from the current position to the end (0 if the object cannot seek)."""
    try:
        here = handle.tell()
        end = handle.seek(0, io.SEEK_END)
        handle.seek(here)
        return max(end - here, 0)
    except (OSError, AttributeError, ValueError):
        return 0
