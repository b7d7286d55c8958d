"""``aruco-abs-orient markers``: the marker map YAML from a survey (the arguments).

In: a survey file (CSV id,E,N,H, Leica GSI-8/16, or four corners per marker), the markers' size, dictionary,
tolerance, survey σ and origin. Out: the marker map of :func:`aruco_abs_orient.survey.marker_map_from_points`
written atomically, and one line saying what it holds. Exit status: 0, 2 a bad option or survey file.
"""

from __future__ import annotations

import argparse

from ...errors import ConfigurationError
from ...table import DECIMAL_MARKS, DELIMITERS
from ..options import add_marker_kind

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "markers", help="marker map YAML from a survey: CSV id,E,N,H, Leica GSI-8/16, or four corners per marker",
        description="Build the marker map from the survey: points named by the marker id (7 or M7) are centres; "
                    "7.1 .. 7.4 are a marker's corners measured reflectorless (top-left, top-right, bottom-right, "
                    "bottom-left seen from the front), from which its centre and face normal come, after a check "
                    "that they form a square of --size in a plane (the offending point is named). The YAML gets "
                    "each marker's normal (the detector then ignores a marker seen from behind) and, with --origin, "
                    "the local origin that ROS works relative to.",
        epilog="examples:\n  aruco-abs-orient markers survey.gsi --size 0.19 --out markers.yaml\n"
               "  aruco-abs-orient markers corners.csv --size 0.19 --dictionary DICT_4X4_50 "
               "--origin 2600000 1200000 400 --out markers.yaml",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("survey", help="CSV (id, E, N, H) or GSI-8/16 file of the surveyed points")
    p.add_argument("--delimiter", choices=DELIMITERS, metavar="D",
                   help="the CSV's field delimiter: , ; tab or blank (default: detected)")
    p.add_argument("--decimal", choices=DECIMAL_MARKS, metavar="MARK",
                   help="the CSV's decimal mark: . or , (default: detected; a row that reads two ways is refused)")
    add_marker_kind(p)
    p.add_argument("--tolerance", type=float, default=0.01, metavar="M",
                   help="largest distance of a corner from the fitted square (default 0.01 m)")
    p.add_argument("--sigma", type=float, default=0.002, metavar="M", help="survey 1-σ per marker (default 0.002 m)")
    p.add_argument("--origin", type=float, nargs=3, metavar=("E", "N", "H"),
                   help="local origin for national grids (the MS60 driver's ~origin must be the same)")
    p.add_argument("--out", required=True, metavar="YAML", help="marker map to write (atomically)")
    p.set_defaults(handler=run)
    return p


def run(a: argparse.Namespace) -> int:
    """``markers``: 0 the marker map written, 2 a bad option or survey file."""
    from ...survey import marker_map_from_points, read_points

    if not a.size > 0 or not a.tolerance > 0 or not a.sigma > 0:
        raise ConfigurationError("--size, --tolerance and --sigma: expected positive numbers (metres)")
    mm = marker_map_from_points(read_points(a.survey, a.delimiter, a.decimal), a.dictionary, a.size, a.tolerance,
                                a.sigma, a.origin, source=a.survey)
    mm.save(a.out)
    with_normal = sum(m.normal is not None for m in mm)
    print(f"wrote {a.out}: {len(mm)} marker(s) ({with_normal} from their corners, with normals), {a.dictionary}, "
          f"size {a.size:g} m" + (f", origin {a.origin}" if a.origin else ""))
    return 0

