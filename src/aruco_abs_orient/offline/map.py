"""``aruco-abs-orient map BAG``: the marker map from the recording itself, the markers not surveyed.

Reads the recording without ROS (a bag, split bags, or a video with its VO trajectory and prism log): the
odometry, lever arms and prism track, then every ``--every``-th image searched whole for every marker of the
dictionary (``calibrate.collect_observations`` without a map: centres and corners). The network
(:func:`aruco_abs_orient.mapping.map_markers`) places each marker in the total station's frame with its
covariance, tied further by ``--control`` markers where they agree; it writes the markers YAML that
``process``, ``calibrate`` and the node read (each marker with its σ, 3-σ ellipsoid, normal σ, redundancy
and test), a report (``<out>_report.md``) and the plan (``<out>_plan.png``); ``--compare`` names the markers
that moved since an older map. The camera's mounting, readout and lenses are the ``--calibration`` file's (or
the bag's /tf_static and the params' lenses); ``--boresight``/``--readout`` estimate them too.

Exit codes: 0 written, 1 no marker could be placed (why, and what to drive), 2 bad input.
Units: seconds, metres inside; millimetres and degrees in what is printed.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time

import numpy as np

from ..calibration import HEADING_MODELS, Recording, load_calibration
from ..errors import AbsOrientError
from ..mapping import MappingError, MapUnknowns, map_markers
from ..mapping.compare import compare_maps
from ..mapping.model import format_xyz
from ..mapping.output import mapped_map, mapped_yaml, plot_plan, report_markdown
from ..markers import ARUCO_DICTIONARIES, MarkerMap
from ..params import load_params
from ..tum import atomic_write_text
from .bagio import bag_name, read_bag_data
from .calibrate import collect_observations
from .cli import BAGS_HELP, _add_topics, _topics, add_params_option, add_video_inputs, video_recording

__all__ = ["add_parser", "run", "load_control", "report_paths"]

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
    p.add_argument("--size", type=float, required=True, metavar="M", help="black square side, metres")
    p.add_argument("--dictionary", choices=ARUCO_DICTIONARIES, default="DICT_4X4_50", metavar="DICT",
                   help="ArUco dictionary (default DICT_4X4_50)")
    p.add_argument("--time-offset", type=float, default=0.0, metavar="S",
                   help="camera stamps = total-station time + S seconds (see `timesync`; default 0)")
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
                   help="how the prism track's direction measures the map->odom yaw: vo_yaw (the platform drives "
                        "where base_link x points; what auto means here) or vo_track (a platform that crabs)")
    p.add_argument("--compare", metavar="YAML", help="an older map (mapped or surveyed): report the markers that moved "
                   "beyond their sigma")
    p.add_argument("--every", type=int, default=1, metavar="N",
                   help="search every N-th image only (default 1: all; each sighting sharpens the map)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_params_option(p, "detection section (the marker search), calibration section (the network's model: knots, "
                         "track headings, gates) and mapping section (when a marker is seen enough, its tests)")
    _add_topics(p)
    add_video_inputs(p)
    p.set_defaults(func=run)
    return p


def load_control(path: str, dictionary: str, size: float, sigma: float) -> MarkerMap:
    """The control markers of ``path``: a markers YAML (.yaml, .yml) or a survey file (``survey.read_points``)."""
    if path.lower().endswith((".yaml", ".yml")):
        control = MarkerMap.load(path)
        if control.dictionary != dictionary:
            raise MappingError(f"{path}: dictionary {control.dictionary}, but --dictionary {dictionary}: expected the "
                               "same markers")
        return control
    from ..survey import marker_map_from_points, read_points

    return marker_map_from_points(read_points(path), dictionary, size, sigma=sigma, source=path)


def report_paths(out: str):
    """The report and plan written beside the markers YAML ``out``: ``site/markers.yaml`` →
    ``site/markers_report.md``, ``site/markers_plan.png``."""
    root, ext = os.path.splitext(out)
    root = root if ext in (".yaml", ".yml") else out
    return root + "_report.md", root + "_plan.png"


def _fail(msg: str, code: int = 2) -> int:
    print(f"aruco-abs-orient map: error: {msg}", file=sys.stderr)
    return code


def run(args: argparse.Namespace) -> int:
    """The ``map`` sub-command: 0 written, 1 nothing could be placed, 2 bad input."""
    if args.every < 1:
        return _fail(f"--every: expected an integer ≥ 1, got {args.every}")
    for name in ("size", "control_sigma"):
        if not (math.isfinite(getattr(args, name)) and getattr(args, name) > 0):
            return _fail(f"--{name.replace('_', '-')}: expected metres > 0, got {getattr(args, name)}")
    if args.readout_ms is not None and not (math.isfinite(args.readout_ms) and 0.0 <= args.readout_ms < 1000.0):
        return _fail(f"--readout-ms: expected milliseconds in [0, 1000), got {args.readout_ms}")
    if not math.isfinite(args.time_offset):
        return _fail(f"--time-offset: expected a finite number of seconds, got {args.time_offset}")
    out_dir = os.path.dirname(os.path.abspath(args.out))
    if not os.path.isdir(out_dir) or not os.access(out_dir, os.W_OK):
        return _fail(f"{args.out}: the directory {out_dir} does not exist or is not writable")
    topics = _topics(args)
    try:
        control = (load_control(args.control, args.dictionary, args.size, args.control_sigma) if args.control
                   else MarkerMap([], args.dictionary))
        old = MarkerMap.load(args.compare) if args.compare else None
        calibration = load_calibration(args.calibration) if args.calibration else {}
        recording = video_recording(args, control) or args.bag
        data = read_bag_data(recording, topics)
        tunables = load_params(args.params)
        obs = collect_observations(recording, None, topics, progress=not args.quiet, detector_params=tunables.detection,
                                   data=data, every=args.every, label="map: detect", dictionary=args.dictionary)
    except AbsOrientError as e:
        return _fail(str(e))
    name = bag_name(recording)
    if len(data.prism_stamps) < 2:
        return _fail(f"{name}: no prism track: the map needs the total station's prism positions", 1)
    readout = 1e-3 * args.readout_ms if args.readout_ms is not None else float(calibration.get("readout", 0.0))
    rec = Recording(obs.times, obs.ids, obs.bearings, obs.sigmas, data.odom, data.prism_stamps + args.time_offset,
                    data.prism_positions, control, calibration.get("camera", data.base_T_camera),
                    calibration.get("prism", data.base_T_prism), obs.rows,
                    calibration.get("lenses", tunables.pipeline.lenses()))
    params = tunables.calibration
    if args.heading_model is not None:
        params = dataclasses.replace(params, heading_model=args.heading_model)
    t0 = time.perf_counter()
    try:
        unknowns = MapUnknowns(args.boresight, args.readout, args.refine_time_offset)
        result = map_markers(rec, obs.corners, args.size, unknowns, params, tunables.mapping, readout)
    except MappingError as e:
        return _fail(f"{name}: cannot map the markers: {e}", 1)
    elapsed = time.perf_counter() - t0
    mm = mapped_map(result, args.size, args.dictionary, origin=control.origin, sizes={m.id: m.size for m in control})
    for k, v in obs.skipped.items():
        result.skipped[k] = result.skipped.get(k, 0) + v
    if not len(mm):
        return _fail(f"{name}: no marker could be placed: " + "; ".join(
            f"{m.id}: {m.reason}" for _, m in sorted(result.markers.items())), 1)
    comparison = compare_maps(mm, old, tunables.mapping.compare_alpha) if old is not None else None
    report, plan = report_paths(args.out)
    atomic_write_text(args.out, mapped_yaml(result, mm, name))
    plot_plan(result, plan, os.path.basename(args.out))
    atomic_write_text(report, report_markdown(result, name, os.path.basename(plan), comparison, elapsed))
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
    if comparison is not None:
        for line in comparison.lines(args.compare):
            print(line)
    print(f"wrote {args.out}: {len(mm)} markers ({len(result.with_status('refused'))} refused, "
          f"{len(result.with_status('left out'))} left out) in {elapsed:.1f} s\n      {report}\n      {plan}")
    return 0

