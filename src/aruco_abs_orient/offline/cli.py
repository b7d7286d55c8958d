"""``aruco-abs-orient``: the offline tools, on recorded bags, without a ROS master.

Sub-commands: ``process`` (bag → trajectory, observations, summary), ``timesync`` (camera ↔
total-station time offset), ``evaluate`` (a processed run vs a reference: report and plots),
``calibrate`` (boresight and lever arm of the camera → static-tf YAML), ``map`` (the marker map from the
recording itself → markers YAML).
Bad input gives one line naming the file/topic/field and exit code 2; exit 1 when nothing useful
could be produced.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from dataclasses import replace
from typing import List, Optional

from ..errors import AbsOrientError, ConfigurationError
from ..markers import MarkerMap
from ..params import defaults_yaml, load_params
from ..pipeline import PipelineParams
from ..tum import atomic_write_text
from .bagio import Bags, BagTopics, bag_name, bags_for_shell, expand_bags
from .evaluate import parse_after

VIDEO_EXAMPLES = """video input (no bag: a 360° video, its VO trajectory, the prism log; doc/field_guide.md):
  aruco-abs-orient timesync --video run.mp4 --trajectory frame_trajectory.txt --trajectory-frame camera_optical \
      --prism prism.gsi --lever-arms lever_arms.yaml
  aruco-abs-orient process --video run.mp4 --trajectory frame_trajectory.txt --trajectory-frame camera_optical \
      --prism prism.gsi --lever-arms lever_arms.yaml --markers markers.yaml --out results/ --time-offset -1699999999.633
"""

BAGS_HELP = ("; several bags (a `rosbag record --split` recording, in any order) or a quoted glob such as "
             "'run_*.bag' are read as one recording in time order")

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
""" + VIDEO_EXAMPLES


def add_video_inputs(p: argparse.ArgumentParser) -> None:
    """The options of a recording without a bag (video + VO trajectory + prism log)."""
    from .prism import PRISM_FORMATS
    from .video import TRAJECTORY_FRAMES

    g = p.add_argument_group("video input, instead of a bag (doc/field_guide.md: The video workflow)")
    g.add_argument("--video", metavar="FILE", help="equirectangular MP4/MOV/MKV (frame times: container timestamps)")
    g.add_argument("--trajectory", metavar="TUM", help="VO trajectory on the video's clock (stella_vslam's "
                   "frame_trajectory.txt, evo): t x y z qx qy qz qw")
    g.add_argument("--trajectory-frame", choices=TRAJECTORY_FRAMES, default="base_link",
                   help="the frame the trajectory gives: base_link, camera (x forward at the image centre, y "
                        "left, z up) or camera_optical (stella_vslam/OpenVSLAM: x right, y down, z forward); "
                        "default base_link")
    g.add_argument("--prism", metavar="FILE", help="prism log on the total station's clock: CSV t,x,y,z, the "
                   "ms60_driver ~log, or a GSI-16 tracking export (time in word 71)")
    g.add_argument("--prism-format", choices=PRISM_FORMATS, default="auto", help="(default auto)")
    g.add_argument("--lever-arms", metavar="YAML", help="base_link_to_camera / base_link_to_prism {xyz, rpy_deg} "
                   "(the format `calibrate` writes; --calibration works too)")
    g.add_argument("--video-start", choices=("zero", "creation"), default="zero",
                   help="the video clock starts at 0 or at the creation time in its metadata (default zero)")


class InputOptionsError(ConfigurationError):
    """The options do not name one complete recording: which option is missing or too much."""


def video_recording(a: argparse.Namespace, marker_map: Optional[MarkerMap] = None):
    """The VideoRecording the options describe, or None when no --video was given; InputOptionsError for an
    incomplete set (which option is missing) or a video given together with bags."""
    if not getattr(a, "video", None):
        if getattr(a, "bag", None) in (None, [], ""):
            raise InputOptionsError("no input: expected a bag, or --video with --trajectory, --prism and --lever-arms")
        return None
    from ..calibration import load_calibration
    from .video import VideoRecording

    if a.bag:
        raise InputOptionsError("a bag and --video given: expected one recording (a bag, or a video with its files)")
    missing = [o for o, v in (("--trajectory", a.trajectory), ("--prism", a.prism),
                              ("--lever-arms (or --calibration)", a.lever_arms or getattr(a, "calibration", None)))
               if not v]
    if missing:
        raise InputOptionsError(f"--video {a.video}: missing {', '.join(missing)}")
    levers = load_calibration(a.lever_arms or a.calibration)
    origin = marker_map.origin if marker_map is not None and marker_map.origin is not None else (0.0, 0.0, 0.0)
    return VideoRecording(a.video, a.trajectory, a.prism, levers["camera"], levers["prism"], a.trajectory_frame,
                          a.video_start, tuple(float(x) for x in origin), a.prism_format,
                          lever_arms=a.lever_arms or a.calibration)


def _add_topics(p: argparse.ArgumentParser) -> None:
    d = BagTopics()
    g = p.add_argument_group("topics and frames")
    g.add_argument("--image-topic", default=d.image, help=f"360° images, CompressedImage or Image (default {d.image})")
    g.add_argument("--tf-topic", default=d.tf, help=f"(default {d.tf})")
    g.add_argument("--tf-static-topic", default=d.tf_static, help=f"(default {d.tf_static})")
    g.add_argument("--prism-topic", default=d.prism, help=f"PointStamped in map (default {d.prism})")
    g.add_argument("--odom-frame", default=d.odom_frame, help=f"(default {d.odom_frame})")
    g.add_argument("--base-frame", default=d.base_frame, help=f"(default {d.base_frame})")
    g.add_argument("--camera-frame", default=d.camera_frame, help=f"(default {d.camera_frame})")
    g.add_argument("--prism-frame", default=d.prism_frame, help=f"(default {d.prism_frame})")
    g.add_argument("--imu-topic", default=d.imu, metavar="TOPIC",
                   help="sensor_msgs/Imu for roll and pitch (orientation, or gravity at standstill; default: none, "
                        "the tilt comes from the markers and the odometry)")


def _topics(a: argparse.Namespace) -> BagTopics:
    return BagTopics(a.image_topic, a.tf_topic, a.tf_static_topic, a.prism_topic, a.odom_frame, a.base_frame,
                     a.camera_frame, a.prism_frame, a.imu_topic)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="aruco-abs-orient", description="Absolute orientation from ArUco markers in 360° images: offline tools.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    p = sub.add_parser("process", help="bag → TUM trajectory of base_link in map, observations CSV, summary JSON",
                       description="Process a recording as the node would, without a ROS master and without "
                       "dropping frames: detect the markers in every image, the yaw of base_link from each "
                       "(with the prism and the lever arms), the map->odom filter; write trajectory.tum, "
                       "observations.csv and summary.json to --out, and check the run's own consistency "
                       "(self-checks: warnings with the likely cause and the command that fixes it).",
                       epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bag", nargs="*", help="ROS 1 bag with the images, /tf, /tf_static and the prism" + BAGS_HELP)
    p.add_argument("--markers", required=True, help="marker map YAML (doc/field_guide.md: The marker map)")
    p.add_argument("--out", required=True, help="output directory (created; files are replaced atomically)")
    p.add_argument("--time-offset", type=float, default=0.0, metavar="S",
                   help="camera stamps = total-station time + S seconds (see `timesync`; default 0)")
    p.add_argument("--calibration", metavar="YAML",
                   help="lever arms and camera rotation from this calibration file (written by `calibrate`) "
                        "instead of the bag's /tf_static")
    p.add_argument("--jpeg-reduce", type=int, choices=(1, 2, 4, 8),
                   help=f"decode images at 1/N resolution (default {PipelineParams.jpeg_reduce}: full; faster, less "
                        "accurate); overrides the params file's pipeline.jpeg_reduce")
    p.add_argument("--no-prism", action="store_true",
                   help="markers only: ignore the prism, each frame's pose from a resection on its markers (>= 3, "
                        "or 2 with the tilt); see the field guide, 'Without a total station'")
    p.add_argument("--full-coordinates", action="store_true",
                   help="also write trajectory.csv: t, E, N, H (the map origin added back) and roll, pitch, heading "
                        "in degrees, for a surveyor")
    add_params_option(p, "pipeline, detection, tracking and filter sections")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_topics(p)
    add_video_inputs(p)

    p = sub.add_parser("timesync", help="camera/VO ↔ total-station time offset of a recording",
                       description="The camera/VO ↔ total-station time offset of a recording: phase coherence of "
                       "the VO yaw with the prism track's heading (the paper's cross-correlation printed beside "
                       "it); with --markers refined with the marker bearings (sub-millisecond where the VO "
                       "drifts; detects the markers in every N-th image, the slow part).",
                       epilog="examples:\n  aruco-abs-orient timesync run.bag --plot results/\n"
                       "  aruco-abs-orient timesync run.bag --markers markers.yaml --every 3\n"
                       "  aruco-abs-orient timesync run.bag --params my_params.yaml",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bag", nargs="*", help="ROS 1 bag with /tf (odom→base_link) and the prism (and the images, "
                   "with --markers)" + BAGS_HELP)
    p.add_argument("--markers", metavar="YAML", help="marker map: refine the offset with the marker bearings")
    p.add_argument("--every", type=int, default=3, metavar="N",
                   help="with --markers: search every N-th image (default 3)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--search", type=float, nargs=2, metavar=("MIN", "MAX"),
                   help="offsets searched, seconds (default -1 1 for a bag; for a video every offset at which the "
                        "trajectory and the prism log overlap by 10 s or more)")
    p.add_argument("--plot", metavar="DIR", help="write the coherence curve to DIR/timesync.png")
    p.add_argument("--min-confidence", type=float, default=0.3, metavar="C",
                   help="refuse an estimate whose confidence (0-1) is below C (default 0.3)")
    add_params_option(p, "timesync section (the estimate's smoothing, windows and limits) and, with --markers, "
                         "its detection section")
    _add_topics(p)
    add_video_inputs(p)

    p = sub.add_parser(
        "evaluate", help="report of a processed run: markers agree?, residuals, coverage; errors vs a reference",
        description="The report of a processed run (report.md: a page of headline figures beside the paper's, "
                    "the plots, then tables per marker; report.json; PNG plots). Without --reference it shows what "
                    "the run shows by itself, the paper's own evaluation: the markers' yaws against each other "
                    "(pairwise, per-marker trajectories, paper figs. 11-12), the residuals and their sigma "
                    "consistency, coverage and gaps, and the run's self-checks. With --reference (a TUM "
                    "trajectory of base_link in map) it adds the heading and position errors (and fig. 13).",
        epilog="examples:\n  aruco-abs-orient evaluate results/run1\n"
               "  aruco-abs-orient evaluate results/run1 --reference truth.tum --overview run1.bag markers.yaml\n"
               "  aruco-abs-orient evaluate results/run1 --reference truth.tum --fused results/run1_out.bag --after 5\n"
               "  aruco-abs-orient evaluate results/run1 --reference truth.tum --params my_params.yaml",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", help="output directory of `process` (summary.json, trajectory.tum, observations.csv)")
    p.add_argument("--reference", metavar="TUM", help="TUM file of base_link in map (e.g. a simulation's truth): "
                   "adds the errors against it")
    p.add_argument("--out", help="report directory (default: the run directory)")
    p.add_argument("--fused", metavar="BAG", help="with --reference: also judge /odometry/filtered "
                   "(robot_localization) recorded in BAG by postprocess.launch record:=BAG")
    p.add_argument("--fused-clock-offset", type=float, metavar="S",
                   help="the recorded stamps are on the camera clock: subtract S s (default: the time offset the "
                        "run used, from its summary.json)")
    p.add_argument("--after", type=parse_after, metavar="T",
                   help="judge the fused output from T s after the start of the recording on (e.g. 5), or from "
                        "an absolute total-station stamp with the suffix abs (e.g. 1700000000.5abs); default: "
                        "1 s after its first absolute yaw")
    p.add_argument("--overview", nargs=2, metavar=("BAG_OR_VIDEO", "MARKERS"),
                   help="also draw overview.png (first in the report): a frame of the bag or video (.mp4, .mov, "
                        ".mkv) with its markers above the trajectory")
    add_params_option(p, "evaluation section (the gaps no error is interpolated across, the coverage gaps "
                         "listed, the fused output's settling time)")

    from .calibrate import add_parser as add_calibrate
    from .map import add_parser as add_map

    add_calibrate(sub)
    add_map(sub)

    p = sub.add_parser("params", help="write the documented defaults of every tunable (cfg/params.yaml)",
                       description="Every tunable (pipeline, detection, tracking, filter, timesync, evaluation) "
                       "with its default and its description, as the YAML file --params and the node's ~params "
                       "read. Copy it, keep the lines you change.",
                       epilog="examples:\n  aruco-abs-orient params --out my_params.yaml\n"
                              "  aruco-abs-orient process run.bag --markers markers.yaml --out results/ "
                              "--params my_params.yaml",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", metavar="YAML", help="write it here (default: print it)")
    from ..markers import ARUCO_DICTIONARIES

    p = sub.add_parser(
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
    p.add_argument("--size", type=float, required=True, metavar="M", help="black square side, metres")
    p.add_argument("--dictionary", choices=ARUCO_DICTIONARIES, default="DICT_4X4_50", metavar="DICT",
                   help="ArUco dictionary (default DICT_4X4_50)")
    p.add_argument("--tolerance", type=float, default=0.01, metavar="M",
                   help="largest distance of a corner from the fitted square (default 0.01 m)")
    p.add_argument("--sigma", type=float, default=0.002, metavar="M", help="survey 1-σ per marker (default 0.002 m)")
    p.add_argument("--origin", type=float, nargs=3, metavar=("E", "N", "H"),
                   help="local origin for national grids (the MS60 driver's ~origin must be the same)")
    p.add_argument("--out", required=True, metavar="YAML", help="marker map to write (atomically)")

    p = sub.add_parser(
        "video-to-bag", help="a video recording (video + VO trajectory + prism log) as a ROS 1 bag for rosbag play",
        description="Write the video, its VO trajectory and the prism log as a ROS 1 bag in the package's topic "
                    "layout (JPEG images, /tf, /tf_static, the prism), streamed frame by frame. The frames and the "
                    "odometry are moved onto the total station's clock with --time-offset (from `timesync`), so "
                    "the bag is processed with --time-offset 0 and plays with one clock.",
        epilog="example:\n  aruco-abs-orient video-to-bag --video run.mp4 --trajectory vo.tum --prism prism.csv "
               "--lever-arms lever_arms.yaml --time-offset -1699999999.633 --out run.bag",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, metavar="BAG", help="bag to write (atomically)")
    p.add_argument("--time-offset", type=float, default=0.0, metavar="S",
                   help="video clock = total-station clock + S seconds (see `timesync`; default 0)")
    p.add_argument("--quality", type=int, default=90, metavar="Q", help="JPEG quality 1-100 (default 90)")
    p.add_argument("--markers", metavar="YAML", help="marker map: its origin is subtracted from the prism positions")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_topics(p)
    add_video_inputs(p)
    return parser


def add_params_option(p: argparse.ArgumentParser, sections: str) -> None:
    """``--params YAML`` on a sub-command with tunables; ``sections``: the ones of cfg/params.yaml it reads."""
    p.add_argument("--params", metavar="YAML", help="a params file: the tunables to change from their defaults, "
                   "any subset of cfg/params.yaml (`aruco-abs-orient params` writes it with every default and its "
                   f"meaning); this command reads its {sections}")



def process_command(bag: Bags, markers: str, time_offset: float, calibration: Optional[str] = None) -> str:
    """The ``process`` command line that uses an estimate (printed after ``use:``): the bag(s) and marker
    map as given (``markers`` already shell-quoted or a placeholder), the output in ``results/<bag name>``."""
    stem = os.path.splitext(os.path.basename(bag_name(bag)))[0] or "run"
    cmd = (f"aruco-abs-orient process {bags_for_shell(bag)} --markers {markers} --out {shlex.quote('results/' + stem)} "
           f"--time-offset {time_offset:.4f}")
    return cmd + (f" --calibration {shlex.quote(calibration)}" if calibration else "")


def _fail(msg: str, code: int = 2) -> int:
    print(f"aruco-abs-orient: error: {msg}", file=sys.stderr)
    return code


def cmd_process(a: argparse.Namespace) -> int:
    from ..calibration import load_calibration
    from .process import RunSetup, process_bag

    marker_map = MarkerMap.load(a.markers)
    if a.no_prism and len(marker_map) < 3:
        return _fail(f"{a.markers}: --no-prism needs at least 3 markers in the map for a resection, it has "
                     f"{len(marker_map)}")
    calibration = load_calibration(a.calibration) if a.calibration else None
    tunables = load_params(a.params)
    recording = video_recording(a, marker_map) or a.bag
    try:
        os.makedirs(a.out, exist_ok=True)
    except OSError as e:
        return _fail(f"{a.out}: cannot create the output directory: {e.strerror}")
    if not os.access(a.out, os.W_OK):
        return _fail(f"{a.out}: output directory is not writable")
    params = tunables.pipeline if a.jpeg_reduce is None else replace(tunables.pipeline, jpeg_reduce=a.jpeg_reduce)
    setup = RunSetup(a.time_offset, _topics(a), calibration, a.full_coordinates, progress=not a.quiet)
    result = process_bag(recording, marker_map, a.out, setup,
                         tunables._replace(pipeline=replace(params, markers_only=a.no_prism)))
    s = result.summary
    print(json.dumps({k: s[k] for k in ("frames", "frames_with_pose", "skipped", "real_time_factor")}, default=float))
    for w in s["warnings"]:
        print(f"aruco-abs-orient: warning: {w}", file=sys.stderr)
    print(f"wrote {result.trajectory_path}\n      {result.observations_path}\n      {result.summary_path}"
          + "".join(f"\n      {p}" for p in result.extra_paths))
    return 0 if s["frames_with_pose"] else 1


def cmd_timesync(a: argparse.Namespace) -> int:
    from ..timesync import TimeSyncError
    from .sync import estimate_bag_offset

    if a.every < 1:
        return _fail(f"--every: expected an integer ≥ 1, got {a.every}")
    tunables = load_params(a.params)
    marker_map = MarkerMap.load(a.markers) if a.markers else None
    recording = video_recording(a, marker_map) or a.bag
    try:
        out = estimate_bag_offset(recording, _topics(a), tuple(a.search) if a.search else None, plot_dir=a.plot,
                                  marker_map=marker_map, every=a.every, progress=not a.quiet, params=tunables)
    except TimeSyncError as e:
        return _fail(f"no time offset: {e}", 1)
    est, base = out["timesync"], out["timesync_baseline"]
    print(f"time offset (camera = total station + offset): {1e3 * est.offset:+.1f} ms ± {1e3 * est.sigma:.1f} ms "
          f"(confidence {est.confidence:.2f}, phase coherence)")
    if hasattr(base, "offset"):
        print(f"paper's cross-correlation baseline:             {1e3 * base.offset:+.1f} ms (one-frame resolution)")
    else:
        print(f"paper's cross-correlation baseline: {base['not_available']}")
    if "plot" in out:
        print(f"wrote {out['plot']}")
    refined = out.get("timesync_markers")
    if refined is not None:
        if hasattr(refined, "offset"):
            print(f"refined with the marker bearings:               {1e3 * refined.offset:+.1f} ms ± "
                  f"{1e3 * refined.sigma:.1f} ms (confidence {refined.confidence:.2f}, "
                  f"{refined.n_samples} bearings)")
            if refined.confidence >= a.min_confidence:
                est = refined
        else:
            print(f"no refinement with the marker bearings: {refined['not_available']}")
    if est.confidence < a.min_confidence:
        return _fail(f"no time offset: confidence {est.confidence:.2f} < {a.min_confidence} (the coherence peak is "
                     "weak: record longer, with more turns of varying rate, or give --markers)", 1)
    markers = shlex.quote(a.markers) if a.markers else "<markers.yaml>"
    hint = "" if a.markers else "   (give your marker map)"
    print(f"use: {process_command(recording, markers, est.offset)}{hint}")
    return 0


def cmd_evaluate(a: argparse.Namespace) -> int:
    from .evaluate import evaluate_run

    if a.fused and not a.reference:
        return _fail("--fused needs --reference: the EKF's output is judged against a reference trajectory")
    params = load_params(a.params).evaluation
    overview = None
    if a.overview:
        from .evaluate import overview_figure

        os.makedirs(a.out or a.run, exist_ok=True)
        overview = overview_figure(os.path.join(a.out or a.run, "overview.png"), a.overview[0], a.run, a.reference,
                                   MarkerMap.load(a.overview[1]))
    res = evaluate_run(a.run, a.reference, a.out, params, fused=a.fused, fused_clock_offset=a.fused_clock_offset,
                       after=a.after, overview=overview)
    for quantity, value, paper, _ in res["headline"]:
        print(f"{quantity}: {value}" + (f" (paper: {paper})" if paper != "–" else ""))
    for note in res["notes"]:
        print(f"aruco-abs-orient: check: {note.split(' ([')[0]}", file=sys.stderr)
    print(f"wrote {res['report_md']}\n      {res['report_json']}")
    return 0


def cmd_params(a: argparse.Namespace) -> int:
    text = defaults_yaml()
    if a.out:
        atomic_write_text(a.out, text)
        print(f"wrote {a.out}")
    else:
        print(text, end="")
    return 0


def cmd_markers(a: argparse.Namespace) -> int:
    from ..survey import marker_map_from_points, read_points

    if not a.size > 0 or not a.tolerance > 0 or not a.sigma > 0:
        return _fail("--size, --tolerance and --sigma: expected positive numbers (metres)")
    mm = marker_map_from_points(read_points(a.survey), a.dictionary, a.size, a.tolerance, a.sigma, a.origin,
                                source=a.survey)
    mm.save(a.out)
    with_normal = sum(m.normal is not None for m in mm)
    print(f"wrote {a.out}: {len(mm)} marker(s) ({with_normal} from their corners, with normals), {a.dictionary}, "
          f"size {a.size:g} m" + (f", origin {a.origin}" if a.origin else ""))
    return 0


def cmd_video_to_bag(a: argparse.Namespace) -> int:
    from .video_to_bag import video_to_bag

    if not 1 <= a.quality <= 100:
        return _fail(f"--quality: expected 1-100, got {a.quality}")
    a.bag = None
    recording = video_recording(a, MarkerMap.load(a.markers) if a.markers else None)  # raises without --video
    r = video_to_bag(recording, a.out, a.time_offset, a.quality, progress=not a.quiet, topics=_topics(a))
    print(f"wrote {r.path}: {r.frames} images (JPEG quality {a.quality}), {r.prism_samples} prism samples, "
          f"{os.path.getsize(r.path) / 1e6:.1f} MB in {r.seconds:.1f} s; process it with --time-offset 0")
    if r.skipped:
        print(f"aruco-abs-orient: warning: {r.skipped} frame(s) outside the trajectory left out", file=sys.stderr)
    if r.stopped:
        print(f"aruco-abs-orient: warning: {r.stopped}", file=sys.stderr)
    return 0 if r.frames else 1


def main(argv: Optional[List[str]] = None) -> int:
    parser = build_parser()
    a = parser.parse_args(argv)
    try:
        if getattr(a, "bag", None):
            a.bag = expand_bags(a.bag)
        if a.command in ("calibrate", "map"):
            return a.func(a)
        return {"process": cmd_process, "timesync": cmd_timesync, "evaluate": cmd_evaluate,
                "params": cmd_params, "markers": cmd_markers, "video-to-bag": cmd_video_to_bag}[a.command](a)
    except AbsOrientError as e:  # every error of the package: its message says what, where, what was expected
        return _fail(str(e))
    except KeyboardInterrupt:
        return _fail("interrupted", 130)


if __name__ == "__main__":
    sys.exit(main())
