"""Delimited number tables as instruments and spreadsheets write them: read one way, or refused.

In: the text of a CSV-like file (:func:`aruco_abs_orient.tum.read_text`: byte-order mark, encoding and
binary files are handled there), the number of fields a row has and which of them are numbers, and
optionally the field delimiter (``,`` ``;`` tab, blank) and decimal mark (``.`` ``,``) the user gave.
Out: a :class:`Table`: each data row's line number and fields (numbers as floats), the header's fields,
the delimiter and decimal mark used.

Contract: every reading (delimiter × decimal mark) still possible is tried on every data row; the one
under which each row has the expected fields, numbers where numbers belong, is used. When no reading
fits, the first row that does not fit the best one is named (file:line). When two readings fit and give
different numbers, the first row that reads two ways is named, e.g. ``7;1,234;5,678;400`` (1.234 m, or
1234 m with a thousands separator), and the user is told to give ``--delimiter``/``--decimal``; a
spreadsheet's ``3;1,5;2,5;0,3`` reads only as 1.5, 2.5, 0.3. Thousands separators (``'``, or the mark that
is not the decimal one) are accepted in groups of three. ``#`` lines and blank lines are skipped; the
first row may be a header (names, not numbers); fields may be quoted. ROS-free, Python 3.8.
"""

from __future__ import annotations

import csv
import re
from typing import Dict, List, NamedTuple, Optional, Sequence, Tuple

__all__ = ["Table", "read_table", "DELIMITERS", "DECIMAL_MARKS", "delimiter_name"]

#: ``--delimiter`` values → the delimiter (None: runs of blanks)
DELIMITERS: Dict[str, Optional[str]] = {",": ",", ";": ";", "tab": "\t", "blank": None}
DECIMAL_MARKS = (".", ",")

_GROUPED = {".": r"\d{1,3}(?:[,']\d{3})+", ",": r"\d{1,3}(?:[.']\d{3})+"}
_NUMBER = {mark: re.compile(r"[+-]?(?:(?:" + _GROUPED[mark] + r"|\d+)(?:" + re.escape(mark) + r"\d*)?|"
                            + re.escape(mark) + r"\d+)(?:[eE][+-]?\d+)?|[+-]?(?:nan|inf|infinity)", re.IGNORECASE)
           for mark in DECIMAL_MARKS}


class Table(NamedTuple):
    """The data rows (``(line number, fields)``: numbers as float, the rest as str), the header's fields
    (lower case; None without a header), the delimiter (None: blanks) and the decimal mark used."""

    rows: List[Tuple[int, list]]
    header: Optional[List[str]]
    delimiter: Optional[str]
    decimal: str


def delimiter_name(delimiter: Optional[str]) -> str:
    """How a delimiter is named in messages and to ``--delimiter``."""
    return next(k for k, v in DELIMITERS.items() if v == delimiter)


def _split(text: str, delimiter: Optional[str]) -> List[str]:
    """The fields of a row (a spreadsheet's quotes removed)."""
    if delimiter is None:
        return [f.strip('"') for f in text.split()]
    return [f.strip() for f in next(csv.reader([text], delimiter=delimiter))]


def _number(text: str, mark: str) -> Optional[float]:
    if not _NUMBER[mark].fullmatch(text):
        return None
    other = "," if mark == "." else "."
    return float(text.replace("'", "").replace(other, "").replace(mark, "."))


def _reading(delimiter: Optional[str], mark: str) -> str:
    return f"'{delimiter_name(delimiter)}' between fields, '{mark}' decimal mark"


def _parse(text: str, delimiter: Optional[str], mark: str, numeric: Sequence[int], width: Optional[int]):
    """The row's fields with numbers converted, or None when it does not fit (field count, a number)."""
    fields = _split(text, delimiter)
    if (len(fields) != width) if width is not None else (len(fields) <= max(numeric)):
        return None
    out: list = list(fields)
    for i in numeric:
        value = _number(fields[i], mark)
        if value is None:
            return None
        out[i] = value
    return out


def read_table(path: str, text: str, numeric: Sequence[int], width: Optional[int], error: type, what: str,
               delimiter: Optional[str] = None, decimal: Optional[str] = None,
               header_columns=None) -> Table:
    """Read ``text`` (the contents of ``path``) as a table of rows of ``width`` fields (None: at least up to
    the last of ``numeric``), fields ``numeric`` (indices) numbers. ``delimiter`` (a :data:`DELIMITERS` key)
    and ``decimal`` (``.`` or ``,``): given by the user, else detected. ``header_columns``: a function of
    the header's lower-case fields → the indices of the numeric columns (None when it does not name
    them), for files whose header says which column is which; their rows then have any width. ``error``
    (an exception class) and ``what`` (the row expected, e.g. ``'id, E, N, H'``) for the one-line
    messages. See the module docstring for the rules."""
    if delimiter is not None and delimiter not in DELIMITERS:
        raise error(f"delimiter: expected one of {', '.join(DELIMITERS)}, got {delimiter!r}")
    if decimal is not None and decimal not in DECIMAL_MARKS:
        raise error(f"decimal mark: expected '.' or ',', got {decimal!r}")
    delims = [DELIMITERS[delimiter]] if delimiter is not None else list(DELIMITERS.values())
    marks = [decimal] if decimal is not None else list(DECIMAL_MARKS)
    readings = [(d, m) for d in delims for m in marks if not (d == "," and m == ",")]
    if not readings:
        raise error(f"{path}: ',' between fields and ',' as the decimal mark: give another --delimiter or --decimal")
    lines = [(n, line.strip()) for n, line in enumerate(text.splitlines(), 1)]
    lines = [(n, line) for n, line in lines if line and not line.startswith("#")]
    if not lines:
        raise error(f"{path}: no data rows: expected {what} per line")
    results = []
    for d, m in readings:
        header, cols, wide, rows, failed = None, list(numeric), width, [], None
        for k, (n, line) in enumerate(lines):
            parsed = _parse(line, d, m, cols, wide)
            if parsed is None and k == 0 and not any(_number(f, m) is not None for f in _split(line, d)):
                header = [f.lower() for f in _split(line, d)]
                named = header_columns(header) if header_columns is not None else None
                if named is not None:
                    cols, wide = list(named), None
                continue
            if parsed is None:
                failed = (n, line)
                break
            rows.append((n, [parsed[i] for i in cols] if wide is None else parsed))
        if not rows and failed is None:  # a header and nothing else: no data row read this way
            failed = lines[0]
        results.append(((d, m), header, rows, failed))
    fitting = [r for r in results if r[3] is None]
    if not fitting:
        (d, m), _, rows, (n, line) = max(results, key=lambda r: len(r[2]))
        shown = repr(line if len(line) <= 80 else line[:80] + "…")
        how = _reading(d, m) if rows or len(readings) == 1 else "any delimiter (, ; tab blank) and decimal mark (. ,)"
        raise error(f"{path}:{n}: expected {what} with {how}, got {shown}")
    first = fitting[0]
    for other in fitting[1:]:
        for (n, a), (_, b) in zip(first[2], other[2]):
            if not all(x == y or (x != x and y != y) for x, y in zip(a, b)):  # NaN reads as NaN both ways
                line = dict(lines)[n]
                raise error(f"{path}:{n}: {line!r} reads two ways: {_row(a)} ({_reading(*first[0])}) or "
                            f"{_row(b)} ({_reading(*other[0])}); give "
                            + ("--decimal" if first[0][0] == other[0][0] else "--delimiter and --decimal"))
    (d, m), header, rows, _ = first
    return Table(rows, header, d, m)


def _row(fields: list) -> str:
    return ", ".join(f"{f:g}" if isinstance(f, float) else str(f) for f in fields)
