"""``aruco-abs-orient calibrate BAG``: boresight (and lever arm) of the camera from a recording.

Reads the bag without ROS (``bagio``): odometry, lever arms and prism in a first pass, then the
images streamed one by one, each searched whole for the map's markers (``tracking.MarkerTracker``
without a prediction, so the nominal calibration cannot bias what is found). Every observation
(time, id, camera-frame bearing, σ, image row) goes to :func:`aruco_abs_orient.calibration.calibrate` with the
odometry trajectory and the prism track moved onto the camera clock (prism stamp + ``time_offset``).
Writes the static-tf YAML read by ``live.launch``/``postprocess.launch`` and a launch file beside it
(``calibration.yaml`` → ``calibration.launch``: the same static tfs, to roslaunch or ``<include>``).

Units: seconds, metres, radians inside; degrees and millimetres in what is printed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import shlex
import sys
from typing import List, Optional

import numpy as np

from ..calibration import (
    HEADING_MODELS,
    Calibration,
    CalibrationError,
    CalibrationParams,
    Recording,
    Unknowns,
    calibrate,
    launch_snippet,
    static_tf_yaml,
)
from ..camera import SINGLE_CENTRE, DualFisheye
from ..detection import DetectionError, DetectorParams, MarkerDetector, decode_jpeg
from ..errors import AbsOrientError
from ..markers import MarkerMap
from ..params import load_params
from ..pipeline import row_fraction
from ..tracking import MarkerTracker
from ..tum import atomic_write_text
from .bagio import BagData, BagTopics, bag_name, iter_images, read_bag_data
from .cli import add_params_option, add_video_inputs, process_command, video_recording

__all__ = ["CalibrateResult", "collect_observations", "calibrate_bag", "add_parser", "run"]

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


class CalibrateResult:
    """Observations of a bag as arrays (see :func:`collect_observations`)."""

    def __init__(self, data: BagData, times, ids, bearings, sigmas, frames: int, skipped: dict, rows=None,
                 corners=None):
        self.data = data
        self.times = np.asarray(times, dtype=float).reshape(-1)          # s, camera clock
        self.ids = np.asarray(ids, dtype=int).reshape(-1)
        self.bearings = np.asarray(bearings, dtype=float).reshape(-1, 3)  # unit, camera frame
        self.sigmas = np.asarray(sigmas, dtype=float).reshape(-1)        # rad
        # image row of each, v/H − ½ (pipeline.row_fraction): the rolling shutter's time within the frame
        self.rows = np.zeros(len(self.times)) if rows is None else np.asarray(rows, dtype=float).reshape(-1)
        # corner bearings (N, 4, 3) of each, ArUco order (None: not kept)
        self.corners = None if corners is None else np.asarray(corners, dtype=float).reshape(-1, 4, 3)
        self.frames = frames                                              # images searched
        self.skipped = skipped


def collect_observations(bag: str, marker_map: Optional[MarkerMap], topics: Optional[BagTopics] = None,
                         progress: bool = True, detector_params: Optional[DetectorParams] = None,
                         data: Optional[BagData] = None, every: int = 1,
                         label: str = "calibrate: detect", dictionary: str = "DICT_4X4_50") -> CalibrateResult:
    """Every marker observation of ``bag`` (with its corners): whole-frame detection of the map's markers in every
    ``every``-th image (30 fps frames a few cm apart add little but detection time), or of every marker of
    ``dictionary`` when ``marker_map`` is None (a map made from the recording); ``label`` names the progress bar
    (the command that runs it)."""
    if every < 1:
        raise CalibrationError(f"every: expected an integer ≥ 1, got {every}")
    topics = topics or BagTopics()
    data = data or read_bag_data(bag, topics)
    if marker_map is None:
        find = MarkerDetector(dictionary, detector_params).detect
    else:
        tracker = MarkerTracker(marker_map, detector_params)

        def find(grey):
            return tracker.process(grey, None).observations
    times: List[float] = []
    ids: List[int] = []
    bearings: List[np.ndarray] = []
    sigmas: List[float] = []
    rows: List[float] = []
    corners: List[np.ndarray] = []
    skipped: dict = {}
    frames = 0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=data.image_count, unit="frame", desc=label, dynamic_ncols=True)
    images = iter_images(bag, topics)
    try:
        for k, (stamp, payload) in _until_broken(images, skipped):
            if bar is not None:
                bar.update(1)
            if k % every:
                continue
            frames += 1
            try:
                if payload is None or not math.isfinite(stamp):
                    raise DetectionError("undecodable image message")
                grey = decode_jpeg(payload) if isinstance(payload, bytes) else payload
                found = find(grey)
                row = row_fraction(np.array([o.centre for o in found]).reshape(-1, 3), grey.shape[0])
            except DetectionError as e:
                key = f"bad image: {str(e).split(':')[0]}"
                skipped[key] = skipped.get(key, 0) + 1
                continue
            for o, f in zip(found, row):
                times.append(stamp)
                ids.append(o.id)
                bearings.append(o.centre)
                sigmas.append(o.sigma)
                rows.append(float(f))
                corners.append(o.corners)
    finally:
        if bar is not None:
            bar.close()
    return CalibrateResult(data, times, ids, bearings, sigmas, frames, skipped, rows, np.array(corners))


def _until_broken(images, skipped: dict):
    """``enumerate(images)`` up to a recording broken half-way (a video that cannot be decoded to its end):
    the frames before are kept, the reason is counted in ``skipped``."""
    k = 0
    while True:
        try:
            item = next(images)
        except StopIteration:
            return
        except AbsOrientError as e:  # the bag or video reader's own errors
            skipped[f"reading stopped: {e}"] = 1
            return
        yield k, item
        k += 1


def calibrate_bag(bag: str, marker_map: MarkerMap, time_offset: float = 0.0, topics: Optional[BagTopics] = None,
                  progress: bool = True, unknowns: Optional[Unknowns] = None,
                  params: Optional[CalibrationParams] = None,
                  observations: Optional[CalibrateResult] = None, lenses: DualFisheye = SINGLE_CENTRE,
                  readout: float = 0.0) -> Calibration:
    """Calibrate the camera of ``bag`` against ``marker_map``.

    ``time_offset`` (s): camera stamps = total-station time + ``time_offset`` (``timesync``'s sign);
    ``unknowns`` (:class:`~aruco_abs_orient.calibration.Unknowns`, default the boresight only): with
    ``time_offset`` it is refined (the result's ``time_offset_delta`` is added to it); ``lever_arm`` the
    camera's origin; ``readout`` the camera's rolling-shutter readout time (the images' stamps are their
    middle rows' capture times; row v of H is captured at stamp + (v/H − ½)·readout).
    ``observations``: a :func:`collect_observations` result to reuse (detection is the slow part).
    ``lenses``: the camera's two lenses as known (``camera.DualFisheye``): fixed, or the start of their estimate.
    ``readout`` (s): the camera's rolling-shutter readout as known: fixed, or the start of its estimate.
    Raises BagError (unusable bag) or CalibrationError (the recording cannot determine it: why).
    """
    obs = observations or collect_observations(bag, marker_map, topics, progress)
    d = obs.data
    if len(d.prism_stamps) < 2:
        raise CalibrationError(f"{bag_name(bag)}: no prism track: the calibration needs the total station's "
                               "prism positions")
    rec = Recording(obs.times, obs.ids, obs.bearings, obs.sigmas, d.odom, d.prism_stamps + time_offset,
                    d.prism_positions, marker_map, d.base_T_camera, d.base_T_prism, obs.rows, lenses)
    cal = calibrate(rec, unknowns, params, readout=readout)
    for k, v in obs.skipped.items():
        cal.skipped[k] = cal.skipped.get(k, 0) + v
    return cal


# ----------------------------------------------------------------------------- CLI


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
    p.add_argument("--time-offset", type=float, default=0.0, metavar="S",
                   help="camera stamps = total-station time + S seconds (see `timesync`; default 0)")
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
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    d = BagTopics()
    g = p.add_argument_group("topics and frames")
    for name in ("image", "tf", "tf_static", "prism"):
        g.add_argument(f"--{name.replace('_', '-')}-topic", default=getattr(d, name),
                       help=f"(default {getattr(d, name)})")
    for name in ("odom_frame", "base_frame", "camera_frame", "prism_frame"):
        g.add_argument(f"--{name.replace('_', '-')}", default=getattr(d, name), help=f"(default {getattr(d, name)})")
    add_params_option(p, "detection section (the marker search) and calibration section (the solve)")
    add_video_inputs(p)
    p.set_defaults(func=run)
    return p


def launch_path(out: str) -> str:
    """The launch file written beside the calibration YAML ``out``: ``site/calibration.yaml`` →
    ``site/calibration.launch``."""
    root, ext = os.path.splitext(out)
    return (root if ext in (".yaml", ".yml") else out) + ".launch"


def _fail(msg: str, code: int = 2) -> int:
    print(f"aruco-abs-orient calibrate: error: {msg}", file=sys.stderr)
    return code


def run(args: argparse.Namespace) -> int:
    """The ``calibrate`` sub-command: 0 written, 1 the recording cannot determine it, 2 bad input."""
    topics = BagTopics(args.image_topic, args.tf_topic, args.tf_static_topic, args.prism_topic, args.odom_frame,
                       args.base_frame, args.camera_frame, args.prism_frame)
    if args.every < 1:
        return _fail(f"--every: expected an integer ≥ 1, got {args.every}")
    if not (math.isfinite(args.readout_ms) and 0.0 <= args.readout_ms < 1000.0):
        return _fail(f"--readout-ms: expected milliseconds in [0, 1000), got {args.readout_ms}")
    if not math.isfinite(args.time_offset):
        return _fail(f"--time-offset: expected a finite number of seconds, got {args.time_offset}")
    out_dir = os.path.dirname(os.path.abspath(args.out))
    if not os.path.isdir(out_dir) or not os.access(out_dir, os.W_OK):
        return _fail(f"{args.out}: the directory {out_dir} does not exist or is not writable")
    try:
        marker_map = MarkerMap.load(args.markers)
        recording = video_recording(args, marker_map) or args.bag
        data = read_bag_data(recording, topics)
        tunables = load_params(args.params)
        obs = collect_observations(recording, marker_map, topics, progress=not args.quiet, data=data,
                                   every=args.every, detector_params=tunables.detection)
    except AbsOrientError as e:
        return _fail(str(e))
    try:
        params = tunables.calibration
        if args.heading_model is not None:
            params = dataclasses.replace(params, heading_model=args.heading_model)
        cal = calibrate_bag(recording, marker_map, args.time_offset, topics, observations=obs, params=params,
                            unknowns=Unknowns(args.lever_arm, args.refine_time_offset, args.readout, args.lenses),
                            lenses=tunables.pipeline.lenses(), readout=1e-3 * args.readout_ms)
    except CalibrationError as e:
        return _fail(f"{bag_name(recording)}: cannot calibrate: {e}", 1)
    text = static_tf_yaml(cal, data.base_T_camera, data.base_T_prism)
    snippet = launch_snippet(cal, data.base_T_camera, data.base_T_prism, topics.base_frame, topics.camera_frame,
                             topics.prism_frame)
    launch = launch_path(args.out)
    atomic_write_text(args.out, text)
    atomic_write_text(launch, f"<launch>\n{snippet}</launch>\n")
    print(json.dumps(cal.report_dict(), default=float))
    print(f"platform model: {cal.heading_model_reason}")
    for warning in cal.warnings:
        print(f"note: {warning}")
    print(f"wrote {args.out}\n      {launch}  (the static tfs: roslaunch it, or "
          f"<include file=\"{os.path.abspath(launch)}\"/>)")
    if cal.readout_estimated:
        print(f"rolling-shutter readout: {1e3 * cal.readout:.1f} ms ± {1e3 * cal.readout_sigma:.1f} ms")
    if cal.time_offset_estimated:
        offset = args.time_offset + cal.time_offset_delta
        print(f"time offset refined with the marker bearings: {1e3 * offset:+.1f} ms ± "
              f"{1e3 * cal.time_offset_sigma:.1f} ms (given {1e3 * args.time_offset:+.1f} ms)")
        print(f"use: {process_command(recording, shlex.quote(args.markers), offset, args.out)}")
    return 0
