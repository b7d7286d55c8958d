"""How every picture of the package is drawn and written: the canvas, the style, the title that is the answer.

In: a size in pixels (:func:`figure`: a matplotlib Figure on an Agg canvas, no pyplot state), a drawn figure and
the answer it gives. Out: a PNG written atomically (:func:`save_figure`, never a half-written plot) whose
``Title`` text chunk holds the answer (:func:`png_title` reads it back, so programs and tests read what a person
reads); :func:`_finish` puts the answer above the axes as the figure's title, wrapped to its width, and saves.
The contract every plot shares: :data:`WIDTH` px wide, 12 pt text (:func:`_style`), :data:`_BAD` for what is
wrong. matplotlib is imported inside the functions only, with matplotlib 3.1's API (Noetic). What the pictures
show is ``plots.py``'s (and ``mapping/output.py``'s).
"""

from __future__ import annotations

import io
import math
import struct
import textwrap
import zlib
from typing import Optional

from .tum import atomic_write_bytes

__all__ = ["WIDTH", "figure", "save_figure", "png_title"]

WIDTH = 1000                    # px: the width every plot is drawn at (report.md shows it 1:1)
_STYLE = {"font.size": 12, "axes.titlesize": 12, "axes.labelsize": 12, "xtick.labelsize": 11,
          "ytick.labelsize": 11, "legend.fontsize": 10.5, "legend.framealpha": 0.9}
_TITLE_PT = 14
_BAD = "#c0392b"                # what is wrong: a run's offset off the best one, a flagged marker, rejections
_GOOD = "#1f77b4"


def figure(width_px: int, height_px: int, dpi: int = 100):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def _style():
    import matplotlib

    return matplotlib.rc_context(_STYLE)


def save_figure(fig, path: str, title: Optional[str] = None) -> str:
    """Write the figure as PNG atomically (never a half-written plot), with ``title`` as its ``Title`` text (an
    iTXt chunk: UTF-8, whatever matplotlib's version writes)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
    png = buf.getvalue()
    if title:
        body = b"Title\0\0\0\0\0" + title.encode("utf-8")
        chunk = struct.pack(">I", len(body)) + b"iTXt" + body + struct.pack(">I", zlib.crc32(b"iTXt" + body))
        end = 8 + 12 + struct.unpack(">I", png[8:12])[0]          # after the IHDR chunk
        png = png[:end] + chunk + png[end:]
    atomic_write_bytes(path, png)
    return path


def png_title(path: str) -> str:
    """The ``Title`` text of a PNG written by :func:`save_figure` ('' when it has none)."""
    with open(path, "rb") as f:
        data = f.read()
    pos = 8
    while pos + 8 <= len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        if kind == b"iTXt" and body.startswith(b"Title\0"):
            compressed, rest = body[6], body[8:]
            text = rest.split(b"\0", 2)[2]
            return (zlib.decompress(text) if compressed else text).decode("utf-8")
        pos += 12 + n
    return ""


def _title(fig, answer: str) -> float:
    """The answer as the figure's title, wrapped to its width; returns the height it takes (figure fraction)."""
    chars = int(fig.get_figwidth() * 72 / (0.62 * _TITLE_PT))
    text = textwrap.fill(answer, chars)
    fig.suptitle(text, fontsize=_TITLE_PT, fontweight="bold", y=1.0 - 0.08 / fig.get_figheight(), va="top")
    return (0.06 + 0.25 * (text.count("\n") + 1)) / fig.get_figheight()


def _finish(fig, path: str, answer: str) -> str:
    """The answer as the figure's title, the axes laid out below it (room for their own titles), saved."""
    top = 1.0 - _title(fig, answer) - 0.32 / fig.get_figheight()
    fig.tight_layout()         # (matplotlib ≥ 3.3 leaves room for the title itself, 3.1 does not)
    fig.subplots_adjust(top=min(fig.subplotpars.top, top))
    return save_figure(fig, path, answer)


def _deg(x: float) -> str:
    """An angle (rad) in degrees, 3 decimals."""
    return f"{math.degrees(x):.3f}°"
