"""``aruco-abs-orient process``: a recording → trajectory.tum, observations.csv, summary.json (the arguments).

In: the recording (bags, or a video with its trajectory and prism log), the marker map, the time offset, an
optional calibration and params file. Out: what :func:`aruco_abs_orient.offline.process.process_bag` writes, a
few aligned lines for people (or ``--json``), its warnings on stderr and the next step. Exit status: 0 written,
1 no pose or a marker map that does not fit (``--force`` writes anyway), 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from dataclasses import replace

from ...errors import ConfigurationError, NoResultError
from ...markers import MarkerMap
from ...params import load_params
from ...pipeline import PipelineParams
from ..bagio import bag_name
from ..options import (
    BAGS_HELP,
    add_params_option,
    add_time_offset,
    add_topics,
    add_video_inputs,
    output_directory,
    print_lines,
    topics_from,
    video_recording,
)

__all__ = ["add_parser", "run"]

EXAMPLES = """examples:
  aruco-abs-orient process run.bag --markers markers.yaml --out results/ --time-offset 0.367
  aruco-abs-orient process run.bag --markers markers.yaml --out results/ --time-offset 0.367 \\
      --calibration calibration.yaml
  aruco-abs-orient process run.bag --markers markers.yaml --out results/ --image-topic /theta/image/compressed
  aruco-abs-orient process run.bag --markers markers.yaml --out results/ --no-prism --imu-topic /imu/data
  aruco-abs-orient process --video run.mp4 --trajectory frame_trajectory.txt --trajectory-frame camera_optical \\
      --prism prism.gsi --lever-arms lever_arms.yaml --markers markers.yaml --out results/ \\
      --time-offset -1699999999.633
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "process", help="bag → TUM trajectory of base_link in map, observations CSV, summary JSON",
        description="Process a recording as the node would, without a ROS master and without "
                    "dropping frames: detect the markers in every image, the yaw of base_link from each "
                    "(with the prism and the lever arms), the map->odom filter; write trajectory.tum, "
                    "observations.csv and summary.json to --out, and check the run's own consistency "
                    "(self-checks: warnings with the likely cause and the command that fixes it).",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bag", nargs="*", help="ROS 1 bag with the images, /tf, /tf_static and the prism" + BAGS_HELP)
    p.add_argument("--markers", required=True, help="marker map YAML (doc/field_guide.md: The marker map)")
    p.add_argument("--out", required=True, help="output directory (created; files are replaced atomically)")
    add_time_offset(p)
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
    p.add_argument("--force", action="store_true",
                   help="write the trajectory even when the marker map does not fit the recording (the map check: "
                        "another site's map, rotated, shifted, scaled, a wrong origin)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON line (for programs)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_topics(p)
    add_video_inputs(p)
    p.set_defaults(handler=run)
    return p


def run(a: argparse.Namespace) -> int:
    """``process``: 0 a trajectory written, 1 none (no pose, or a marker map that does not fit), 2 bad input."""
    from ...calibration import load_calibration
    from ...mapcheck import DOES_NOT_FIT
    from ..process import RunSetup, process_bag

    marker_map = MarkerMap.load(a.markers)
    if a.no_prism and len(marker_map) < 3:
        raise ConfigurationError(f"{a.markers}: --no-prism needs at least 3 markers in the map for a resection, it "
                                 f"has {len(marker_map)}")
    calibration = load_calibration(a.calibration) if a.calibration else None
    tunables = load_params(a.params)
    recording = video_recording(a, marker_map) or a.bag
    output_directory(a.out)
    params = tunables.pipeline if a.jpeg_reduce is None else replace(tunables.pipeline, jpeg_reduce=a.jpeg_reduce)
    setup = RunSetup(a.time_offset, topics_from(a), calibration, a.full_coordinates, progress=not a.quiet,
                     force=a.force)
    result = process_bag(recording, marker_map, a.out, setup,
                         tunables._replace(pipeline=replace(params, markers_only=a.no_prism)))
    s = result.summary
    check = s["map_check"]
    refused = check["status"] == DOES_NOT_FIT and not a.force
    if a.json:
        print(json.dumps({**{k: s[k] for k in ("frames", "frames_with_pose", "skipped", "real_time_factor")},
                          "map_check": check["status"], "trajectory": result.trajectory_path or None}, default=float))
    else:
        frames, posed = s["frames"], s["frames_with_pose"]
        skipped = sum(s["skipped"].values())
        first = s["filter"]["initialised_at"]
        rtf = s["real_time_factor"]
        print_lines([
            ("images", f"{frames}"),
            ("with a pose", f"{posed} ({100.0 * posed / max(frames, 1):.1f} %)"
             + (f", from {first - s['recording_start_s']:.1f} s into the recording" if first is not None else "")),
            ("skipped", f"{skipped}" + (" (" + ", ".join(f"{k}: {v}" for k, v in sorted(s["skipped"].items()))
                                        + ")" if skipped else "")),
            ("marker map", check["message"] if check["status"] != DOES_NOT_FIT else "does not fit (below)"),
            ("speed", f"{rtf:.2f} × real time ({s['wall_time_s']:.1f} s for {s['bag_duration_s']:.1f} s of recording)"
             if rtf else "-"),
        ])
    for w in s["warnings"]:
        if not (refused and w == check["message"]):
            print(f"aruco-abs-orient: warning: {w}", file=sys.stderr)
    paths = [p for p in (result.trajectory_path, result.observations_path, result.summary_path) if p]
    print("wrote " + "\n      ".join(paths + list(result.extra_paths)))
    if refused:
        raise NoResultError(f"{check['message']}; no trajectory written ({a.markers} against {bag_name(recording)}: "
                            "check the map, or --force to write it anyway)")
    if not s["frames_with_pose"]:
        return 1
    if not a.json:
        print(f"use: aruco-abs-orient evaluate {shlex.quote(a.out)}   (the report: next step)")
    return 0

