"""A rendered scenario (``aruco-abs-orient-synth`` output) as the files a 360° camera user has.

``export_video(scenario_dir)`` writes into ``scenario_dir/video`` (or ``out_dir``):

- ``video.mp4``: the scenario's frames (mp4v through ``cv2.VideoWriter``, at the scenario's frame
  rate; ``codec="ffv1"``: ``video.avi``, lossless); its clock starts at 0 at the first frame, and
  the MP4's ``mvhd`` creation time is the first frame's camera stamp (whole seconds), as a camera
  writes it (an AVI has no such field);
- ``vo.tum``: the odometry (``odom → base_link`` of the bag, or of the camera with ``frame``) on the
  video's clock (stamps − the first frame's camera stamp), as stella_vslam writes it for a video;
- ``prism.csv`` (``t,x,y,z``, total-station clock) or ``prism.gsi`` (GSI-16, time in word 71);
- ``lever_arms.yaml``: ``base_link_to_camera`` and ``base_link_to_prism`` of the bag's /tf_static;
- with ``origin`` (E, N, H): the prism log, ``markers.yaml`` (with ``origin:``) and ``truth.tum`` in full
  coordinates, as a surveyor's files in a national grid are.

Run as ``python -m aruco_abs_orient.synthetic.export DIR [--origin E N H] [--prism-format gsi]``.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from typing import List, NamedTuple, Optional, Sequence

import numpy as np

from ..detection import decode_jpeg
from ..errors import ConfigurationError, run
from ..markers import MarkerMap
from ..offline.bagio import iter_images, read_bag_data
from ..offline.video import ROS_FROM_OPTICAL, TRAJECTORY_FRAMES, set_mp4_creation_time
from ..survey import format_gsi
from ..transforms import make_T, matrix_to_rpy
from ..tum import Trajectory, WriteError, atomic_write_text, read_tum, write_tum

__all__ = ["ExportedVideo", "export_video", "lever_arms_yaml"]


class ExportedVideo(NamedTuple):
    out_dir: str
    video: str
    trajectory: str
    prism: str
    lever_arms: str
    markers: str
    truth: str
    frames: int
    clock_start: float   # s: camera stamp of the first frame (the video's 0)


def lever_arms_yaml(base_T_camera: np.ndarray, base_T_prism: np.ndarray) -> str:
    """The lever arms in the calibration file's format (``calibration.load_calibration`` reads it)."""
    def entry(T) -> str:
        xyz = ", ".join(f"{float(x):.6f}" for x in T[:3, 3])
        rpy = ", ".join(f"{math.degrees(float(a)):.6f}" for a in matrix_to_rpy(T[:3, :3]))
        return f"{{xyz: [{xyz}], rpy_deg: [{rpy}]}}"
    return (f"base_link_to_camera: {entry(base_T_camera)}\n"
            f"base_link_to_prism: {entry(base_T_prism)}\n")


# lossy as a camera's MP4; lossless FFV1 in an AVI (the same pixels, 5× faster to write than PNG frames in a MOV;
# AVI keeps the stamps at n / fps exactly, MKV would round them to 1 ms)
CODECS = {"mp4v": ("video.mp4", "mp4v"), "ffv1": ("video.avi", "FFV1")}


def export_video(scenario_dir: str, out_dir: Optional[str] = None, frame: str = "base_link",
                 origin: Optional[Sequence[float]] = None, prism_format: str = "csv",
                 codec: str = "mp4v") -> ExportedVideo:
    """Write the files (module docstring) of the scenario in ``scenario_dir``; frames are streamed from the
    bag one by one (memory stays flat). ``codec``: mp4v (``video.mp4``) or ffv1 (``video.avi``, lossless:
    the bag's decoded frames exactly, to tell the cost of compression from the rest)."""
    import cv2

    if frame not in TRAJECTORY_FRAMES:
        raise ConfigurationError(f"frame: expected one of {', '.join(TRAJECTORY_FRAMES)}, got {frame!r}")
    out_dir = out_dir or os.path.join(scenario_dir, "video")
    os.makedirs(out_dir, exist_ok=True)
    bag = os.path.join(scenario_dir, "scenario.bag")
    data = read_bag_data(bag)
    shift = np.zeros(3) if origin is None else np.asarray(origin, dtype=float)
    video = os.path.join(out_dir, CODECS[codec][0])
    writer = None
    stamps: List[float] = []
    try:
        for stamp, payload in iter_images(bag):
            grey = decode_jpeg(payload) if isinstance(payload, bytes) else payload
            if writer is None:
                fps = 1.0 / float(np.median(np.diff(data.odom.stamps)))
                fourcc = cv2.VideoWriter_fourcc(*CODECS[codec][1])
                writer = cv2.VideoWriter(video, fourcc, fps, (grey.shape[1], grey.shape[0]), False)
                if not writer.isOpened():
                    raise WriteError(f"{video}: OpenCV cannot write {codec} video here")
            writer.write(grey)
            stamps.append(stamp)
    finally:
        if writer is not None:
            writer.release()
    t0 = stamps[0]
    if video.endswith(".mp4"):
        set_mp4_creation_time(video, t0)
    T = data.odom.transforms
    if frame in ("camera", "camera_optical"):
        T = T @ data.base_T_camera
    if frame == "camera_optical":
        M = make_T(ROS_FROM_OPTICAL, np.zeros(3))
        T = np.linalg.inv(M) @ T @ M
    trajectory = os.path.join(out_dir, "vo.tum")
    write_tum(trajectory, Trajectory.from_transforms(data.odom.stamps - t0, T),
              header=f"{frame} in odom on the video's clock (0 = first frame)")
    full = data.prism_positions + shift
    if prism_format == "gsi":
        prism = os.path.join(out_dir, "prism.gsi")
        atomic_write_text(prism, format_gsi([(str(k + 1), p) for k, p in enumerate(full)], gsi16=True, unit="8",
                                            extra=[{71: f"{t:.3f}"} for t in data.prism_stamps]))
    else:
        prism = os.path.join(out_dir, "prism.csv")
        atomic_write_text(prism, "t,x,y,z\n" + "".join(f"{t:.9f},{p[0]:.7f},{p[1]:.7f},{p[2]:.7f}\n"
                                                       for t, p in zip(data.prism_stamps, full)))
    levers = os.path.join(out_dir, "lever_arms.yaml")
    atomic_write_text(levers, lever_arms_yaml(data.base_T_camera, data.base_T_prism))
    markers = MarkerMap.load(os.path.join(scenario_dir, "markers.yaml"))
    markers.origin = None if origin is None else shift
    markers_path = os.path.join(out_dir, "markers.yaml")
    markers.save(markers_path)
    truth = read_tum(os.path.join(scenario_dir, "truth.tum"))
    truth_path = os.path.join(out_dir, "truth.tum")
    full_note = " (full coordinates)" if origin is not None else ""
    write_tum(truth_path, truth._replace(positions=truth.positions + shift),
              header=f"base_link in map at each image's true capture time{full_note}")
    return ExportedVideo(out_dir, video, trajectory, prism, levers, markers_path, truth_path, len(stamps), t0)


def main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(prog="python -m aruco_abs_orient.synthetic.export",
                                description="A rendered scenario as video.mp4 + vo.tum + prism log + lever_arms.yaml")
    p.add_argument("scenario", help="output directory of aruco-abs-orient-synth")
    p.add_argument("--out", help="output directory (default SCENARIO/video)")
    p.add_argument("--frame", choices=TRAJECTORY_FRAMES, default="base_link", help="frame of vo.tum")
    p.add_argument("--origin", type=float, nargs=3, metavar=("E", "N", "H"),
                   help="place the scenario at these full coordinates (prism log, markers.yaml, truth.tum)")
    p.add_argument("--prism-format", choices=("csv", "gsi"), default="csv")
    p.add_argument("--codec", choices=sorted(CODECS), default="mp4v",
                   help="mp4v (video.mp4) or ffv1 (lossless, video.avi)")
    a = p.parse_args(argv)
    return run(p.prog, lambda: _export(a))


def _export(a: argparse.Namespace) -> int:
    r = export_video(a.scenario, a.out, a.frame, a.origin, a.prism_format, a.codec)
    print(f"wrote {r.out_dir}/: {os.path.basename(r.video)} ({r.frames} frames), {os.path.basename(r.trajectory)}, "
          f"{os.path.basename(r.prism)}, lever_arms.yaml, markers.yaml, truth.tum "
          f"(video clock 0 = {r.clock_start:.3f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
