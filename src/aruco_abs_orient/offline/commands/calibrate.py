"""``aruco-abs-orient calibrate``: the camera's mounting (and lever arm, time offset, readout, lenses) (the arguments).

In: the recording, the marker map, the time offset, what to estimate, a params file. Out: the calibration of
:func:`aruco_abs_orient.offline.calibrate.calibrate_bag` as the static-tf YAML that ``live.launch`` and
``postprocess.launch`` read, a launch file beside it (``calibration.yaml`` → ``calibration.launch``: the same
static tfs, to roslaunch or ``<include>``; the directory is created), lines for people (or ``--json``), the
residual plot with ``--plot`` and the ``process`` command to run next. Before the solve, the map check: a marker
map that does not fit the recording is refused, saying how it is off (``--force`` calibrates anyway). Exit
status: 0 written, 1 the recording cannot determine it (why), 2 bad input.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import shlex
import sys
from typing import List

from ...calibration import HEADING_MODELS, Calibration, CalibrationError, Unknowns, launch_snippet, static_tf_yaml
from ...errors import ConfigurationError, NoResultError
from ...mapcheck import DOES_NOT_FIT, MapVerdict
from ...markers import MarkerMap
from ...params import load_params
from ...tum import atomic_write_text
from ..bagio import bag_name, read_bag_data
from ..calibrate import calibrate_bag, collect_observations, map_check
from ..commandlines import process_command
from ..options import (
    add_params_option,
    add_time_offset,
    add_topics,
    add_video_inputs,
    output_directory,
    print_lines,
    topics_from,
    video_recording,
)

__all__ = ["add_parser", "run", "launch_path"]

EXAMPLES = """examples:
  aruco-abs-orient calibrate run.bag --markers markers.yaml --time-offset 0.367 --out calibration.yaml
  aruco-abs-orient calibrate run.bag --markers markers.yaml --lever-arm --out calibration.yaml
  aruco-abs-orient calibrate run.bag --markers markers.yaml --time-offset 0.37 --refine-time-offset --readout \\
      --out calibration.yaml
  aruco-abs-orient calibrate run.bag --markers markers.yaml --time-offset 0.37 --refine-time-offset \\
      --out calibration.yaml
  roslaunch aruco_abs_orient live.launch markers:=markers.yaml calibration:=calibration.yaml

The recording must show markers while the platform DRIVES (straight stretches and gentle curves):
the boresight yaw is separated from the map->odom yaw by the prism track's direction of travel.
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``calibrate`` sub-command on an ``argparse`` sub-parsers object."""
    p = subparsers.add_parser(
        "calibrate", help="boresight (and lever arm) of the camera from a recording → static-tf YAML",
        description="Estimate the camera's boresight rotation in base_link (and optionally its lever arm) "
                    "by least squares over all marker observations of a recording; write the static-tf "
                    "YAML that live.launch/postprocess.launch read, and a launch file beside it (calibration.yaml → "
                    "calibration.launch: the same static tfs by static_transform_publisher, to roslaunch or "
                    "<include>).",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bag", nargs="*", help="ROS 1 bag with the images, /tf, /tf_static and the prism; several "
                   "bags or a quoted glob ('run_*.bag') are one split recording")
    p.add_argument("--markers", required=True, help="marker map YAML (doc/field_guide.md: The marker map)")
    add_time_offset(p)
    p.add_argument("--out", required=True, metavar="YAML",
                   help="calibration YAML to write (atomically); the launch file goes beside it (.yaml → .launch)")
    p.add_argument("--lever-arm", action="store_true", help="also estimate the camera lever arm (3 more unknowns)")
    p.add_argument("--refine-time-offset", action="store_true",
                   help="also estimate the time offset (1 more unknown), starting from --time-offset (from "
                        "`timesync`, within ~0.2 s); prints the refined value to use with `process`")
    p.add_argument("--readout", action="store_true",
                   help="also estimate the camera's rolling-shutter readout time (1 more unknown; the image stamp "
                        "is the middle row's capture time, row v of H at stamp + (v/H - 1/2)*readout); written "
                        "to the calibration YAML (camera_readout_ms), which process and the node read. Needs "
                        "turns with markers above and below the horizon")
    p.add_argument("--readout-ms", type=float, default=0.0, metavar="MS",
                   help="the camera's rolling-shutter readout as known (ms, first to last row; e.g. from a calibration "
                        "run with --readout): used as it is, or with --readout as the start of its estimate; written "
                        "to the calibration YAML (default 0: a global shutter)")
    p.add_argument("--heading-model", choices=HEADING_MODELS, default=None,
                   help="how the prism track's direction separates the boresight yaw from the map->odom yaw: "
                        "against the VO's yaw (vo_yaw: the platform drives where base_link x points), against the "
                        "VO's own direction of travel (vo_track: a platform that crabs), or auto: both fitted, the "
                        "VO's yaw kept unless the two disagree beyond their σ (the platform crabs) or the direction "
                        "of travel is the more precise; the choice and why are printed (default: the calibration "
                        "section's heading_model, auto)")
    p.add_argument("--no-lenses", dest="lenses", action="store_false",
                   help="keep the camera's two lenses as the pipeline section gives them (lens_offset, "
                        "stitch_distance) instead of estimating their offset and relative rotation (by default "
                        "they are estimated, and written to the calibration YAML)")
    p.add_argument("--every", type=int, default=1, metavar="N",
                   help="search every N-th image only (default 1: all; 3 is plenty at 30 fps)")
    p.add_argument("--force", action="store_true",
                   help="calibrate even when the marker map does not fit the recording (the map check)")
    p.add_argument("--json", action="store_true", help="print the estimate as one JSON line (for programs)")
    p.add_argument("--plot", metavar="DIR", help="write DIR/calibration.png: the bearing residuals against azimuth and "
                   "elevation before and after, per lens, with the fitted mounting (evaluate shows it in the report)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_topics(p)
    add_params_option(p, "detection section (the marker search) and calibration section (the solve)")
    add_video_inputs(p)
    p.set_defaults(handler=run)
    return p


def launch_path(out: str) -> str:
    """The launch file written beside the calibration YAML ``out``: ``site/calibration.yaml`` →
    ``site/calibration.launch``."""
    root, ext = os.path.splitext(out)
    return (root if ext in (".yaml", ".yml") else out) + ".launch"


def run(args: argparse.Namespace) -> int:
    """The ``calibrate`` sub-command: 0 written, 1 the recording cannot determine it, 2 bad input."""
    _check_options(args)
    topics = topics_from(args)
    marker_map = MarkerMap.load(args.markers)
    recording = video_recording(args, marker_map) or args.bag
    data = read_bag_data(recording, topics)
    tunables = load_params(args.params)
    obs = collect_observations(recording, marker_map, topics, progress=not args.quiet, data=data,
                               every=args.every, detector_params=tunables.detection)
    check = map_check(obs, marker_map, args.time_offset, tunables.mapcheck)
    if check.status == DOES_NOT_FIT:
        if not args.force:
            raise NoResultError(f"{check.message}; not calibrated ({args.markers} against {bag_name(recording)}: "
                                "check the map, or --force to calibrate anyway)")
        print(f"aruco-abs-orient calibrate: warning: {check.message}", file=sys.stderr)
    params = tunables.calibration
    if args.heading_model is not None:
        params = dataclasses.replace(params, heading_model=args.heading_model)
    try:
        cal = calibrate_bag(recording, marker_map, args.time_offset, topics, observations=obs, params=params,
                            unknowns=Unknowns(args.lever_arm, args.refine_time_offset, args.readout, args.lenses),
                            lenses=tunables.pipeline.lenses(), readout=1e-3 * args.readout_ms)
    except CalibrationError as e:
        raise NoResultError(f"{bag_name(recording)}: cannot calibrate: {e}") from None
    launch = _write(args, cal, data, topics)
    if args.plot:
        from ...plots import plot_calibration

        plot = plot_calibration(os.path.join(args.plot, "calibration.png"), cal, obs.bearings, data.base_T_camera)
        print(f"wrote {plot}")
    report = cal.report_dict()
    offset = args.time_offset + (cal.time_offset_delta if cal.time_offset_estimated else 0.0)
    if args.json:
        print(json.dumps({**report, "map_check": check.status}, default=float))
    else:
        print_lines(_report_lines(cal, report, args.time_offset, check))
    print(f"wrote {args.out}\n      {launch}  (the static tfs: roslaunch it, or "
          f"<include file=\"{os.path.abspath(launch)}\"/>)")
    print(f"use: {process_command(recording, shlex.quote(args.markers), offset, args.out)}   (next step)")
    return 0


def _check_options(args: argparse.Namespace) -> None:
    """ConfigurationError for an option out of range; the output directories made (InputFileError if not)."""
    if args.every < 1:
        raise ConfigurationError(f"--every: expected an integer ≥ 1, got {args.every}")
    if not (math.isfinite(args.readout_ms) and 0.0 <= args.readout_ms < 1000.0):
        raise ConfigurationError(f"--readout-ms: expected milliseconds in [0, 1000), got {args.readout_ms}")
    if not math.isfinite(args.time_offset):
        raise ConfigurationError(f"--time-offset: expected a finite number of seconds, got {args.time_offset}")
    output_directory(os.path.dirname(os.path.abspath(args.out)), args.out)
    if args.plot:
        output_directory(args.plot, "--plot")


def _write(args: argparse.Namespace, cal: Calibration, data, topics) -> str:
    """The calibration YAML ``args.out`` and the launch file beside it (returned), atomically."""
    text = static_tf_yaml(cal, data.base_T_camera, data.base_T_prism)
    snippet = launch_snippet(cal, data.base_T_camera, data.base_T_prism, topics.base_frame, topics.camera_frame,
                             topics.prism_frame)
    launch = launch_path(args.out)
    atomic_write_text(args.out, text)
    atomic_write_text(launch, f"<launch>\n{snippet}</launch>\n")
    return launch


def _report_lines(cal: Calibration, report: dict, given_offset: float, check: MapVerdict) -> List[tuple]:
    """The calibration for people: (label, value with units) rows."""
    rpy, sig = report["boresight_rpy_deg"], report["boresight_sigma_deg"]
    rows = [("boresight roll, pitch, yaw", ", ".join(f"{v:+.3f}° ± {s:.3f}°" for v, s in zip(rpy, sig))),
            ("bearing residual RMS", f"{report['residual_rms_before_deg']:.3f}° before, "
                                     f"{report['residual_rms_after_deg']:.3f}° after"),
            ("observations", f"{report['observations_used']} of {report['observations']} used, "
                             f"{report['markers']} markers, {report['moving_time_s']:.1f} s driving")]
    if cal.time_offset_estimated:
        rows.append(("time offset", f"{1e3 * (given_offset + cal.time_offset_delta):+.1f} ms ± "
                                    f"{1e3 * cal.time_offset_sigma:.1f} ms (refined with the marker bearings; given "
                                    f"{1e3 * given_offset:+.1f} ms)"))
    if cal.readout_estimated:
        rows.append(("rolling-shutter readout", f"{1e3 * cal.readout:.1f} ms ± {1e3 * cal.readout_sigma:.1f} ms"))
    if cal.lever_arm_estimated:
        rows.append(("camera lever arm change", ", ".join(f"{v:+.1f} ± {s:.1f}" for v, s in zip(
            report["lever_arm_delta_mm"], report["lever_arm_sigma_mm"])) + " mm (x, y, z)"))
    if cal.lenses_estimated:
        rows.append(("lens offset", f"{report['lens_offset_mm']:+.2f} mm ± {report['lens_offset_sigma_mm']:.2f} mm "
                                    "(each lens's centre from the camera's, along its axis)"))
        rows.append(("back lens rotation", ", ".join(f"{v:+.3f}° ± {s:.3f}°" for v, s in zip(
            report["lens_rotation_deg"], report["lens_rotation_sigma_deg"])) + " (against the front lens)"))
    rows.append(("each lens's yaw σ", ", ".join(f"{s:.3f}°" for s in report["lens_yaw_sigma_deg"])
                 + f" (front, back; {', '.join(str(n) for n in report['lens_observations'])} observations)"))
    rows.append(("odometry tilt at the start", ", ".join(f"{v:+.3f}° ± {s:.3f}°" for v, s in zip(
        report["odom_tilt_deg"], report["odom_tilt_sigma_deg"])) + " (about map x, y)"))
    rows.append(("platform model", cal.heading_model_reason))
    rows.append(("marker map", check.message))
    rows += [("note", warning) for warning in cal.warnings]
    return rows
