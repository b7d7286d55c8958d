"""What the offline commands' argument parsers share: the recording's options and their reading.

In: an ``argparse`` parser to add options to, or the parsed ``argparse.Namespace``. Out: the topic and frame
options (:func:`add_topics` → :class:`~aruco_abs_orient.offline.bagio.BagTopics`), the options of a recording
without a bag (:func:`add_video_inputs` → :func:`video_recording`), ``--params`` (:func:`add_params_option`),
``--time-offset`` (:func:`add_time_offset`), the markers' ``--size`` and ``--dictionary`` (:func:`add_marker_kind`),
an output directory made and checked (:func:`output_directory`) and aligned result lines
(:func:`print_lines`). Imports no command: the commands import it. Errors: :class:`InputOptionsError` or
InputFileError, one line naming the option or path.
"""

from __future__ import annotations

import argparse
import os
from typing import Optional

from ..errors import ConfigurationError, InputFileError
from ..markers import ARUCO_DICTIONARIES, MarkerMap
from .bagio import BagTopics

__all__ = ["BAGS_HELP", "InputOptionsError", "add_topics", "topics_from", "add_video_inputs", "video_recording",
           "add_params_option", "add_time_offset", "add_marker_kind", "output_directory", "print_lines"]

BAGS_HELP = ("; several bags (a `rosbag record --split` recording, in any order) or a quoted glob such as "
             "'run_*.bag' are read as one recording in time order")


class InputOptionsError(ConfigurationError):
    """The options do not name one complete recording: which option is missing or too much."""


def add_topics(p: argparse.ArgumentParser) -> None:
    """The topic and frame names of a recording (``--image-topic`` … ``--imu-topic``), defaults of BagTopics."""
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


def topics_from(a: argparse.Namespace) -> BagTopics:
    """The BagTopics of the options :func:`add_topics` added."""
    return BagTopics(a.image_topic, a.tf_topic, a.tf_static_topic, a.prism_topic, a.odom_frame, a.base_frame,
                     a.camera_frame, a.prism_frame, a.imu_topic)


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


def add_time_offset(p: argparse.ArgumentParser) -> None:
    """``--time-offset S``: the camera's stamps against the total station's (``timesync``'s result)."""
    p.add_argument("--time-offset", type=float, default=0.0, metavar="S",
                   help="camera stamps = total-station time + S seconds (see `timesync`; default 0)")


def add_marker_kind(p: argparse.ArgumentParser) -> None:
    """``--size M`` (required) and ``--dictionary DICT``: the printed markers."""
    p.add_argument("--size", type=float, required=True, metavar="M", help="black square side, metres")
    p.add_argument("--dictionary", choices=ARUCO_DICTIONARIES, default="DICT_4X4_50", metavar="DICT",
                   help="ArUco dictionary (default DICT_4X4_50)")


def add_params_option(p: argparse.ArgumentParser, sections: str) -> None:
    """``--params YAML`` on a sub-command with tunables; ``sections``: the ones of cfg/params.yaml it reads."""
    p.add_argument("--params", metavar="YAML", help="a params file: the tunables to change from their defaults, "
                   "any subset of cfg/params.yaml (`aruco-abs-orient params` writes it with every default and its "
                   f"meaning); this command reads its {sections}")


def output_directory(path: str, for_file: Optional[str] = None) -> None:
    """Create the directory ``path`` (of the output file ``for_file``, if it is for one) and check it is
    writable; InputFileError naming it otherwise."""
    where = f"{for_file}: the directory {path}" if for_file else f"{path}: the output directory"
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as e:
        raise InputFileError(f"{where.replace(': the ', ': cannot create the ', 1)}: {e.strerror}") from None
    if not os.access(path, os.W_OK):
        raise InputFileError(f"{where} is not writable")


def print_lines(rows) -> None:
    """``(label, value)`` rows as aligned lines for people (the values with their units)."""
    width = max((len(label) for label, _ in rows), default=0)
    for label, value in rows:
        print(f"{label:<{width}}  {value}")
