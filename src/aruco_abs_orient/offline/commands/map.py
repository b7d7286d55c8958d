"""``aruco-abs-orient map``: the marker map from a recording, the markers not surveyed (the arguments).

In: the recording, the markers' size and dictionary, the time offset, the camera's calibration, the control
markers, an older map to compare with, what to estimate besides the markers, a params file. Out: the markers
YAML, report and plan of :mod:`aruco_abs_orient.offline.map`, a line per marker placed, refused or left out,
the boresight/readout/time offset when estimated, the markers that moved. Exit status: 0 written, 1 no marker
could be placed (why, and what to drive), 2 bad input.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np

from ...calibration import HEADING_MODELS, load_calibration
from ...errors import ConfigurationError
from ...mapping import MapUnknowns
from ...mapping.model import format_xyz
from ...markers import MarkerMap
from ...params import load_params
from ..map import load_control, map_recording, write_map
from ..options import (
    BAGS_HELP,
    add_marker_kind,
    add_params_option,
    add_time_offset,
    add_topics,
    add_video_inputs,
    output_directory,
    topics_from,
    video_recording,
)

__all__ = ["add_parser", "run"]

EXAMPLES = """examples:
  aruco-abs-orient map run.bag --size 0.19 --time-offset 0.367 --calibration calibration.yaml --out markers.yaml
  aruco-abs-orient map run.bag --size 0.19 --time-offset 0.367 --boresight --out markers.yaml
  aruco-abs-orient map run.bag --size 0.19 --time-offset 0.367 --calibration calibration.yaml \\
      --control survey.gsi --out markers.yaml
  aruco-abs-orient map run2.bag --size 0.19 --time-offset 0.367 --calibration calibration.yaml \\
      --compare markers.yaml --out markers_run2.yaml
  aruco-abs-orient process run.bag --markers markers.yaml --out results/ --time-offset 0.367 \\
      --calibration calibration.yaml

Drive so that every marker is seen from places several metres apart, from the front and both sides, at 2-8 m
(doc/field_guide.md, 'Without surveying the markers'); the time offset comes from `timesync` (without --markers).
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``map`` sub-command on an ``argparse`` sub-parsers object."""
    p = subparsers.add_parser(
        "map", help="marker map YAML from a recording: the markers placed by the platform, not surveyed",
        description="Place every marker seen in a recording in the total station's frame by a network adjustment "
                    "over its bearings, the prism track and the odometry (the map->odom yaw with its drift, the "
                    "odometry's tilt); write the markers YAML that process, calibrate and the node read, each marker "
                    "with its 3-sigma ellipsoid, normal sigma, the redundancy of its observations and its test "
                    "against the others, a report and the plan. Markers seen too little are refused with what to "
                    "drive; markers that disagree (moved during the recording, two with one id) are left out.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bag", nargs="*", help="ROS 1 bag with the images, /tf, /tf_static and the prism" + BAGS_HELP)
    add_marker_kind(p)
    add_time_offset(p)
    p.add_argument("--out", required=True, metavar="YAML",
                   help="markers YAML to write (atomically); the report and plan go beside it (_report.md, _plan.png)")
    p.add_argument("--control", metavar="FILE",
                   help="control markers: a markers YAML, or a survey file `markers` reads (CSV id,E,N,H, GSI, four "
                        "corners); each one the network agrees with ties the map by its survey's sigma")
    p.add_argument("--control-sigma", type=float, default=0.002, metavar="M",
                   help="survey 1-sigma of the control markers of a survey file (default 0.002 m; a YAML gives its "
                        "own)")
    p.add_argument("--calibration", metavar="YAML",
                   help="the camera's mounting, rolling-shutter readout and lenses from `calibrate` (default: the "
                        "bag's /tf_static, a global shutter and the params' lenses)")
    p.add_argument("--boresight", action="store_true",
                   help="also estimate the camera's boresight (roll, pitch, yaw): without a calibration of the "
                        "camera")
    p.add_argument("--readout", action="store_true",
                   help="also estimate the rolling-shutter readout (needs turns with markers above and below the "
                        "horizon)")
    p.add_argument("--refine-time-offset", action="store_true",
                   help="also estimate the time offset, starting from --time-offset (within ~0.1 s); the refined "
                        "value is printed")
    p.add_argument("--readout-ms", type=float, default=None, metavar="MS",
                   help="the rolling-shutter readout as known (ms; default the calibration file's, else 0)")
    p.add_argument("--heading-model", choices=HEADING_MODELS, default=None,
                   help="how the prism track's direction measures the map->odom yaw: vo_track (against the track "
                        "the odometry predicts for the prism: crab and weave cancel; what auto means here, vo_yaw "
                        "when the odometry has no positions) or vo_yaw (the platform drives where base_link x "
                        "points)")
    p.add_argument("--compare", metavar="YAML", help="an older map (mapped or surveyed): report the markers that moved "
                   "beyond their sigma")
    p.add_argument("--every", type=int, default=1, metavar="N",
                   help="search every N-th image only (default 1: all; each sighting sharpens the map)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_params_option(p, "detection section (the marker search), calibration section (the network's model: knots, "
                         "track headings, gates) and mapping section (when a marker is seen enough, its tests)")
    add_topics(p)
    add_video_inputs(p)
    p.set_defaults(handler=run)
    return p


def _check(args: argparse.Namespace) -> None:
    if args.every < 1:
        raise ConfigurationError(f"--every: expected an integer ≥ 1, got {args.every}")
    for name in ("size", "control_sigma"):
        if not (math.isfinite(getattr(args, name)) and getattr(args, name) > 0):
            raise ConfigurationError(f"--{name.replace('_', '-')}: expected metres > 0, got {getattr(args, name)}")
    if args.readout_ms is not None and not (math.isfinite(args.readout_ms) and 0.0 <= args.readout_ms < 1000.0):
        raise ConfigurationError(f"--readout-ms: expected milliseconds in [0, 1000), got {args.readout_ms}")
    if not math.isfinite(args.time_offset):
        raise ConfigurationError(f"--time-offset: expected a finite number of seconds, got {args.time_offset}")


def run(args: argparse.Namespace) -> int:
    """``map``: 0 written, 1 nothing could be placed (raised), 2 bad input (raised)."""
    _check(args)
    output_directory(os.path.dirname(os.path.abspath(args.out)), args.out)
    control = (load_control(args.control, args.dictionary, args.size, args.control_sigma) if args.control
               else MarkerMap([], args.dictionary))
    old = MarkerMap.load(args.compare) if args.compare else None
    calibration = load_calibration(args.calibration) if args.calibration else {}
    recording = video_recording(args, control) or args.bag
    readout = 1e-3 * args.readout_ms if args.readout_ms is not None else None
    mapped = map_recording(recording, topics_from(args), args.time_offset, args.size, args.dictionary, control,
                           calibration, MapUnknowns(args.boresight, args.readout, args.refine_time_offset),
                           load_params(args.params), readout, args.heading_model, args.every, old,
                           progress=not args.quiet)
    report, plan = write_map(mapped, args.out)
    result, mm = mapped.result, mapped.markers
    for m in result.with_status("mapped"):
        axes = m.ellipsoid(3.0)[0]
        print(f"marker {m.id}: {format_xyz(mm.to_full(m.position), 4)} ± {1e3 * axes[0]:.1f} mm (3-σ, worst axis), "
              f"seen in {m.views} images at {m.ranges[0]:.1f}-{m.ranges[1]:.1f} m from {m.baseline:.1f} m of track")
    for m in result.with_status("refused") + result.with_status("left out"):
        print(f"aruco-abs-orient map: marker {m.id} {m.status}: {m.reason}", file=sys.stderr)
    for w in result.warnings:
        print(f"aruco-abs-orient map: warning: {w}", file=sys.stderr)
    if np.any(np.isfinite(result.boresight_sigma)):
        print("boresight (deg): " + ", ".join(f"{math.degrees(a):+.4f} ± {math.degrees(s):.4f}"
                                            for a, s in zip(result.boresight, result.boresight_sigma)))
    if math.isfinite(result.readout_sigma):
        print(f"rolling-shutter readout: {1e3 * result.readout:.2f} ± {1e3 * result.readout_sigma:.2f} ms")
    if math.isfinite(result.time_offset_sigma):
        offset = args.time_offset + result.time_offset_delta
        print(f"time offset refined with the marker bearings: {1e3 * offset:+.1f} ms ± "
              f"{1e3 * result.time_offset_sigma:.1f} ms (given {1e3 * args.time_offset:+.1f} ms)")
    if mapped.comparison is not None:
        for line in mapped.comparison.lines(args.compare):
            print(line)
    print(f"wrote {args.out}: {len(mm)} markers ({len(result.with_status('refused'))} refused, "
          f"{len(result.with_status('left out'))} left out) in {mapped.elapsed:.1f} s\n      {report}\n      {plan}")
    return 0
