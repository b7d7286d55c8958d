"""``aruco-abs-orient params``: every tunable with its default and meaning, as cfg/params.yaml holds them.

In: ``--out`` (a path) or nothing. Out: :func:`aruco_abs_orient.params.defaults_yaml` written atomically
there, or printed. Exit status: 0, 2 when the file cannot be written.
"""

from __future__ import annotations

import argparse

from ...params import defaults_yaml
from ...tum import atomic_write_text

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "params", help="write the documented defaults of every tunable (cfg/params.yaml)",
        description="Every tunable (pipeline, detection, tracking, filter, tilt, fit, selfcheck, mapcheck, "
                    "timesync, evaluation, calibration) with its default, meaning, unit and range, as the YAML "
                    "file --params reads and the node takes in its namespace (abs_orient.launch params:=FILE). "
                    "Copy it, keep the lines you change.",
        epilog="examples:\n  aruco-abs-orient params --out my_params.yaml\n"
               "  aruco-abs-orient process run.bag --markers markers.yaml --out results/ "
               "--params my_params.yaml",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", metavar="YAML", help="write it here (default: print it)")
    p.set_defaults(handler=run)
    return p


def run(a: argparse.Namespace) -> int:
    """``params``: the documented defaults printed or written; 0 (2: the file cannot be written)."""
    text = defaults_yaml()
    if a.out:
        atomic_write_text(a.out, text)
        print(f"wrote {a.out}")
    else:
        print(text, end="")
    return 0

