"""figures.py: a figure written with its answer as the PNG's Title text reads it back, whatever its characters;
the file is a PNG of the figure's size in pixels."""

from __future__ import annotations

import os
import struct

from aruco_abs_orient.figures import png_title, save_figure


def png_size(path):
    with open(path, "rb") as f:
        head = f.read(24)
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR"
    return struct.unpack(">II", head[16:24])


def test_the_title_survives_a_round_trip_through_the_file(tmp_path):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2, 1), dpi=100)
    FigureCanvasAgg(fig)
    title = "camera ↔ total station: −50.0 ms, ±2σ, 0.3°"        # not Latin-1: stored as UTF-8
    path = save_figure(fig, str(tmp_path / "t.png"), title)
    assert png_title(path) == title and png_size(path) == (200, 100)
    assert png_title(save_figure(fig, str(tmp_path / "u.png"))) == ""
    assert sorted(os.listdir(tmp_path)) == ["t.png", "u.png"]     # no temporary files left
