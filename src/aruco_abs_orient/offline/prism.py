"""The total station's prism log as a file: CSV ``t, x, y, z``, our ``ms60_driver`` log, Leica GSI-16.

- CSV: ``t, x, y, z`` (s, m; comma, semicolon, tab or blank separated, decimal mark ``.`` or ``,``: detected,
  a row that reads two ways refused, :mod:`aruco_abs_orient.table`; an optional header line naming the
  columns ``t``/``time``/``stamp`` and ``x``/``e``/``east``, ``y``/``n``/``north``, ``z``/``h``/``height``);
- the ``~log`` CSV of ``ms60_driver``: ``t,east,north,height`` (ROS time, full coordinates): a CSV as above;
- a GSI-16 (or GSI-8) export of a tracking run: one block per fix, easting/northing/height in words 81-83
  and the instrument time in seconds in a remark word (:data:`GSI_TIME_WORD`, set in the format file).

Stamps are the total station's clock. Rows with NaN/inf are skipped and counted; a row that is not
numbers is an error naming the file and line; a binary file or an unknown encoding, one naming the file.
"""

from __future__ import annotations

import re
from typing import Dict, List, NamedTuple, Optional, Sequence

import numpy as np

from ..errors import InputFileError
from ..survey import SurveyError, gsi_blocks, gsi_number
from ..table import read_table
from ..tum import read_text

__all__ = ["PrismLogError", "PrismLog", "read_prism", "GSI_TIME_WORD", "PRISM_FORMATS"]

GSI_TIME_WORD = 71  # remark 1: seconds of the instrument clock
PRISM_FORMATS = ("auto", "csv", "gsi")
_COLUMNS = {"t": ("t", "time", "stamp", "timestamp"), "x": ("x", "e", "east", "easting"),
            "y": ("y", "n", "north", "northing"), "z": ("z", "h", "height", "up")}


class PrismLogError(InputFileError):
    """A prism log that cannot be used: names the file, the line, what was expected."""


class PrismLog(NamedTuple):
    stamps: np.ndarray        # (N,) s, total-station clock, increasing
    positions: np.ndarray     # (N, 3) m, full coordinates as logged
    skipped: Dict[str, int]
    warnings: List[str]


def read_prism(path: str, fmt: str = "auto") -> PrismLog:
    """Read a prism log (``fmt``: auto, csv or gsi; auto: GSI when its first line looks like GSI)."""
    if fmt not in PRISM_FORMATS:
        raise PrismLogError(f"prism format: expected one of {', '.join(PRISM_FORMATS)}, got {fmt!r}")
    text = read_text(path, PrismLogError, "prism log")
    first = next((x.strip() for x in text.splitlines() if x.strip() and not x.startswith("#")), "")
    if fmt == "gsi" or (fmt == "auto" and re.match(r"^\*?\d{6}[+-]", first)):
        rows, skipped = _gsi_rows(path)
    else:
        rows, skipped = _csv_rows(path, text)
    if len(rows) < 2:
        raise PrismLogError(f"{path}: {len(rows)} prism position(s): expected a tracking log ('t, x, y, z' per line)")
    data = np.array(rows, dtype=float)
    order = np.argsort(data[:, 0], kind="stable")
    data = data[order]
    keep = np.concatenate([[True], np.diff(data[:, 0]) > 0])
    if not np.all(keep):
        skipped["duplicate prism stamp"] = int(np.sum(~keep))
    data = data[keep]
    return PrismLog(data[:, 0], data[:, 1:4], skipped, [])


def _columns(header: Sequence[str]) -> Optional[List[int]]:
    """The indices of the t, x, y, z columns a header names (None when it does not name them all)."""
    cols = [next((i for i, n in enumerate(header) if n in _COLUMNS[k]), None) for k in "txyz"]
    return None if None in cols else cols


def _csv_rows(path: str, text: str):
    table = read_table(path, text, (0, 1, 2, 3), 4, PrismLogError, "'t, x, y, z' (s, m, m, m)",
                       header_columns=_columns)
    rows, skipped = [], {}
    for _, values in table.rows:
        if not all(np.isfinite(values)):
            skipped["NaN/inf prism position"] = skipped.get("NaN/inf prism position", 0) + 1
            continue
        rows.append(values)
    return rows, skipped


def _gsi_rows(path: str):
    rows = []
    try:
        for lineno, data, info in gsi_blocks(path):
            if not all(wi in data for wi in (81, 82, 83)):
                continue
            if GSI_TIME_WORD not in data:
                raise PrismLogError(f"{path}:{lineno}: a fix without its time: expected the instrument time in "
                                    f"seconds in word {GSI_TIME_WORD} (remark 1)")
            rows.append([gsi_number(path, lineno, wi, data, info) for wi in (GSI_TIME_WORD, 81, 82, 83)])
    except SurveyError as e:
        raise PrismLogError(str(e)) from None
    return rows, {}
