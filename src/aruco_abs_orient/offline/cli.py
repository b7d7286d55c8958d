"""``aruco-abs-orient``: the offline tools, on recorded bags (or a video with its files), without a ROS master.

In: the command line. Out: the sub-command's work and its exit status. The sub-commands are the modules of
:mod:`aruco_abs_orient.offline.commands` (``process``, ``timesync``, ``evaluate``, ``calibrate``, ``params``,
``markers``, ``map``, ``video-to-bag``), each registering its own options; this module builds the parser from
:data:`~aruco_abs_orient.offline.commands.COMMANDS`, expands bag globs and dispatches once, inside the one error
boundary (:func:`aruco_abs_orient.errors.run`): bad input gives one line naming the file/topic/field and exit
status 2; 1 when nothing useful could be produced.
"""

from __future__ import annotations

import argparse
import sys
from typing import List, Optional

from ..errors import run
from .bagio import expand_bags
from .commands import COMMANDS

PROG = "aruco-abs-orient"

EXAMPLES = """examples:
  aruco-abs-orient timesync run.bag
  aruco-abs-orient timesync run.bag --markers markers.yaml
  aruco-abs-orient process run.bag --markers markers.yaml --out results/ --time-offset 0.367
  aruco-abs-orient evaluate results/
  aruco-abs-orient evaluate results/ --reference truth.tum
  aruco-abs-orient calibrate run.bag --markers markers.yaml --time-offset 0.367 --out calibration.yaml
  aruco-abs-orient process run.bag --markers markers.yaml --out results/ --time-offset 0.367 \\
      --calibration calibration.yaml
  aruco-abs-orient process run.bag --markers markers.yaml --out results/ --image-topic /theta/image/compressed
  aruco-abs-orient process run.bag --markers markers.yaml --out results/ --no-prism --imu-topic /imu/data
  aruco-abs-orient markers survey.gsi --size 0.19 --out markers.yaml
"""


def build_parser() -> argparse.ArgumentParser:
    """The parser of every sub-command (each module of :data:`COMMANDS` adds its own)."""
    parser = argparse.ArgumentParser(
        prog=PROG, description="Absolute orientation from ArUco markers in 360° images: offline tools.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point of ``aruco-abs-orient``: the exit status of the sub-command."""
    args = build_parser().parse_args(argv)
    return run(PROG, lambda: _dispatch(args))


def _dispatch(args: argparse.Namespace) -> int:
    if getattr(args, "bag", None):
        args.bag = expand_bags(args.bag)
    return args.handler(args)


if __name__ == "__main__":
    sys.exit(main())
