"""A recording without a bag: 360° video + VO trajectory (TUM) + prism log, read as one source.

What a Ricoh Theta / Insta360 / GoPro Max user has: an equirectangular MP4/MOV/MKV, the trajectory
stella_vslam/OpenVSLAM (``frame_trajectory.txt``) or evo wrote, and the total station's prism log.
:class:`VideoRecording` gives ``process``, ``timesync``, ``calibrate`` and ``evaluate`` the same two
things a bag gives them (:mod:`.bagio`): the small data first (:class:`~.bagio.BagData`: odometry,
lever arms, prism), then the frames streamed one by one.

Clocks. Frame times are the container's presentation timestamps (OpenCV's FFmpeg backend,
``CAP_PROP_POS_MSEC`` of each decoded frame), so a variable frame rate is read as recorded. A frame
the camera dropped is a longer gap between two timestamps: the frames around it keep their own times
(nothing shifts), the gap is counted in the warnings. Frames with a timestamp not after the previous
one (duplicates) are skipped and counted. The video clock starts at 0 (``video_start="zero"``) or at
the creation time in its metadata (``"creation"``: MP4/MOV ``mvhd``, whole seconds, UTC); the VO
trajectory is on the same clock as the frames it was computed from (its stamps get the same start
added). The prism log is on the total station's clock: the offset between the two is what
``timesync`` finds, over the whole range where the two overlap (it can be hundreds of seconds, or an
epoch when the video starts at 0).

A video that cannot be decoded to its end keeps the frames before the break; the warning names the
file, the frame number and its time.
"""

from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass
from typing import Iterator, List, Optional, Tuple

import numpy as np

from ..errors import InputFileError
from ..transforms import make_T
from ..tum import Trajectory, TumError, read_tum
from .bagio import BagData, BagTopics
from .prism import read_prism

__all__ = ["VideoError", "VideoRecording", "TRAJECTORY_FRAMES", "VIDEO_EXTENSIONS", "video_frames", "mp4_creation_time",
           "video_summary"]

# the frame a VO trajectory gives: base_link; our camera frame (x = image centre column, y left, z up);
# stella_vslam/OpenVSLAM's camera (x right, y down, z forward; its world frame is its first camera's)
TRAJECTORY_FRAMES = ("base_link", "camera", "camera_optical")
ROS_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
MP4_EPOCH = 2082844800  # s from 1904-01-01 (QuickTime) to 1970-01-01 (Unix)
VIDEO_EXTENSIONS = (".mp4", ".mov", ".mkv", ".avi", ".m4v")
GAP_FACTOR = 1.5        # a frame interval longer than this × the median is a dropped frame (or more)


class VideoError(InputFileError):
    """A video recording that cannot be used: names the file, the frame or line, what was expected."""


def mp4_creation_time(path: str) -> Optional[float]:
    """Creation time (Unix s, UTC) in the ``moov/mvhd`` box of an MP4/MOV; None when the file has no
    such box or it holds 0 (not set)."""
    with open(path, "rb") as f:
        data = f.read()
    box = _find_box(data, 0, len(data), [b"moov", b"mvhd"])
    if box is None:
        return None
    start, _ = box
    version = data[start]
    if version == 1:
        created = struct.unpack(">Q", data[start + 4:start + 12])[0]
    else:
        created = struct.unpack(">I", data[start + 4:start + 8])[0]
    return float(created - MP4_EPOCH) if created else None


def _find_box(data: bytes, begin: int, end: int, path: List[bytes]) -> Optional[Tuple[int, int]]:
    """(payload start, payload end) of the box at ``path`` (ISO BMFF nesting) between ``begin`` and ``end``."""
    i = begin
    while i + 8 <= end:
        size, kind = struct.unpack(">I4s", data[i:i + 8])
        header = 8
        if size == 1:
            size, header = struct.unpack(">Q", data[i + 8:i + 16])[0], 16
        elif size == 0:
            size = end - i
        if size < header:
            return None
        if kind == path[0]:
            if len(path) == 1:
                return i + header, i + size
            return _find_box(data, i + header, min(i + size, end), path[1:])
        i += size
    return None


def set_mp4_creation_time(path: str, unix_seconds: float) -> None:
    """Write ``unix_seconds`` (whole seconds) as the ``mvhd`` creation time of an MP4/MOV in place
    (what a camera does; cv2.VideoWriter leaves it 0)."""
    with open(path, "r+b") as f:
        data = f.read()
        box = _find_box(data, 0, len(data), [b"moov", b"mvhd"])
        if box is None:
            raise VideoError(f"{path}: no moov/mvhd box: not an MP4/MOV file")
        start = box[0]
        value = int(math.floor(unix_seconds)) + MP4_EPOCH
        if data[start] == 1:
            f.seek(start + 4)
            f.write(struct.pack(">Q", value))
        else:
            f.seek(start + 4)
            f.write(struct.pack(">I", value))


def _open_capture(path: str):
    import cv2

    if not os.path.isfile(path):
        raise VideoError(f"{path}: no such video file")
    cap = cv2.VideoCapture(path, cv2.CAP_FFMPEG)
    if not cap.isOpened():
        cap.release()
        raise VideoError(f"{path}: OpenCV's FFmpeg backend cannot open it (expected an MP4, MOV or MKV video)")
    return cap


def video_frames(path: str, start: float = 0.0, grey: bool = True) -> Iterator[Tuple[int, float, np.ndarray]]:
    """``(frame number, time s, image)`` of each decoded frame, time = ``start`` + the frame's
    container timestamp. A frame whose timestamp is not after the previous one is skipped. When decoding
    stops before the frame count the container announces, VideoError names the file, the last good
    frame and its time, after the frames before it have been yielded (nothing before is lost)."""
    import cv2

    cap = _open_capture(path)
    try:
        announced = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        last, k = -math.inf, 0
        while cap.grab():
            t = cap.get(cv2.CAP_PROP_POS_MSEC) * 1e-3
            ok, image = cap.retrieve()
            if not ok or image is None:
                break
            k += 1
            if not t > last:
                continue
            last = t
            if grey and image.ndim == 3:
                image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
            yield k - 1, start + t, image
    finally:
        cap.release()
    if k < announced - 1:
        raise VideoError(_truncation(path, k, start + last, announced))


def _truncation(path: str, k: int, last: float, announced: int) -> str:
    where = f"after frame {k - 1} (t = {last:.3f} s)" if k else "at its first frame"
    return (f"{path}: decoding stopped {where} of the {announced} frames the container announces: "
            f"kept the {k} frame(s) before")


def video_summary(path: str) -> Tuple[int, float, float]:
    """(frame count, frames per second, duration s) the container announces."""
    import cv2

    cap = _open_capture(path)
    try:
        n, fps = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), float(cap.get(cv2.CAP_PROP_FPS))
    finally:
        cap.release()
    return n, fps, n / fps if fps > 0 else float("nan")


def frame_times(path: str, start: float = 0.0) -> Tuple[np.ndarray, List[str]]:
    """The times of the frames (container timestamps + ``start``) without converting the pixels (grab
    only), and what is wrong with them: frames skipped for a timestamp not after the previous one,
    decoding that stops before the announced frame count."""
    import cv2

    cap = _open_capture(path)
    out: List[float] = []
    grabbed = 0
    try:
        announced = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        while cap.grab():
            grabbed += 1
            t = start + cap.get(cv2.CAP_PROP_POS_MSEC) * 1e-3
            if not out or t > out[-1]:
                out.append(t)
    finally:
        cap.release()
    notes = []
    if grabbed > len(out):
        notes.append(f"{path}: {grabbed - len(out)} frame(s) with a timestamp not after the previous one skipped")
    if grabbed < announced - 1:
        notes.append(_truncation(path, grabbed, out[-1] if out else float("nan"), announced))
    return np.asarray(out, dtype=float), notes


@dataclass
class VideoRecording:
    """A recording as files: ``video`` (equirectangular), ``trajectory`` (TUM of ``trajectory_frame`` in
    odom, on the video's clock), ``prism`` (CSV / ms60_driver log / GSI-16, total-station clock),
    ``base_T_camera`` and ``base_T_prism`` (4×4 lever arms: ``calibration.load_calibration`` of a
    small YAML or of ``--calibration``). ``origin`` (E, N, H) is subtracted from the prism positions
    (the marker map's, see :mod:`aruco_abs_orient.markers`). ``video_start``: "zero" or "creation"."""

    video: str
    trajectory: str
    prism: str
    base_T_camera: np.ndarray
    base_T_prism: np.ndarray
    trajectory_frame: str = "base_link"
    video_start: str = "zero"
    origin: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    prism_format: str = "auto"
    lever_arms: str = "<lever-arms.yaml>"   # the file the lever arms came from (for the commands printed)

    def __post_init__(self) -> None:
        if self.trajectory_frame not in TRAJECTORY_FRAMES:
            raise VideoError(f"trajectory frame: expected one of {', '.join(TRAJECTORY_FRAMES)}, "
                             f"got {self.trajectory_frame!r}")
        if self.video_start not in ("zero", "creation"):
            raise VideoError(f"video start: expected 'zero' or 'creation', got {self.video_start!r}")

    @property
    def name(self) -> str:
        return self.video

    def shell_args(self) -> str:
        """The command-line options that name this recording."""
        import shlex

        args = ["--video", self.video, "--trajectory", self.trajectory, "--trajectory-frame", self.trajectory_frame,
                "--prism", self.prism, "--lever-arms", self.lever_arms]
        if self.prism_format != "auto":
            args += ["--prism-format", self.prism_format]
        if self.video_start != "zero":
            args += ["--video-start", self.video_start]
        return " ".join(shlex.quote(x) for x in args)

    @property
    def files(self) -> List[str]:
        return [self.video, self.trajectory, self.prism]

    def clock_start(self) -> float:
        """s added to the container timestamps: 0, or the creation time of the video."""
        if self.video_start == "zero":
            return 0.0
        created = mp4_creation_time(self.video) if os.path.isfile(self.video) else None
        if created is None:
            raise VideoError(f"{self.video}: no creation time in its metadata (moov/mvhd): use the video start 'zero' "
                             "and let timesync find the offset")
        return created

    def odometry(self, start: float) -> Trajectory:
        """odom_T_base_link from the TUM file, its stamps + ``start``."""
        try:
            traj = read_tum(self.trajectory)
        except TumError as e:
            raise VideoError(str(e)) from None
        if len(traj.stamps) < 2:
            raise VideoError(f"{self.trajectory}: {len(traj.stamps)} pose(s): expected a VO trajectory (TUM "
                             "'t x y z qx qy qz qw', one pose per line)")
        order = np.argsort(traj.stamps, kind="stable")
        T = traj.transforms[order]
        if self.trajectory_frame == "camera_optical":
            M = make_T(ROS_FROM_OPTICAL, np.zeros(3))
            T = M @ T @ np.linalg.inv(M)          # world and camera turned into the ROS camera convention
        if self.trajectory_frame in ("camera", "camera_optical"):
            T = T @ np.linalg.inv(self.base_T_camera)  # odom_T_camera · camera_T_base
        stamps = traj.stamps[order] + start
        keep = np.concatenate([[True], np.diff(stamps) > 0])
        return Trajectory.from_transforms(stamps[keep], T[keep])

    def read_data(self, topics: Optional[BagTopics] = None) -> BagData:
        """The recording's data as a bag's first pass gives it (see :func:`.bagio.read_bag_data`)."""
        start = self.clock_start()
        odom = self.odometry(start)
        prism = read_prism(self.prism, self.prism_format)
        times, warnings = frame_times(self.video, start)
        if len(times) == 0:
            raise VideoError(f"{self.video}: no frame could be decoded")
        period = np.diff(times)
        if len(period):
            med = float(np.median(period))
            gaps = period > GAP_FACTOR * med
            if np.any(gaps):
                lost = int(np.sum(np.round(period[gaps] / med) - 1))
                first = int(np.argmax(gaps))
                warnings.append(f"{self.video}: {int(np.sum(gaps))} gap(s) in the frame timestamps (about {lost} "
                                f"dropped frame(s) at {1 / med:.2f} fps; the first after frame {first}, "
                                f"t = {times[first]:.3f} s): the frames keep their own times")
        lo, hi = max(times[0], odom.stamps[0]), min(times[-1], odom.stamps[-1])
        if hi <= lo:
            raise VideoError(f"{self.trajectory}: the trajectory ({odom.stamps[0]:.3f}..{odom.stamps[-1]:.3f} s) and "
                             f"the video {self.video} ({times[0]:.3f}..{times[-1]:.3f} s) do not overlap in time: "
                             "expected the VO stamps on the video's clock (stella_vslam's frame_trajectory.txt of "
                             "this video; with --video-start creation both get the creation time)")
        outside = int(np.sum((times < odom.stamps[0]) | (times > odom.stamps[-1])))
        if outside:
            warnings.append(f"{self.trajectory}: covers {lo:.3f}..{hi:.3f} s; {outside} of {len(times)} frame(s) of "
                            f"{self.video} lie outside it (no odometry: skipped)")
        positions = prism.positions - np.asarray(self.origin, dtype=float)
        return BagData(path=self.video, odom=odom, base_T_camera=np.asarray(self.base_T_camera, dtype=float),
                       base_T_prism=np.asarray(self.base_T_prism, dtype=float), prism_stamps=prism.stamps,
                       prism_positions=positions, image_count=len(times), image_format="raw",
                       start=float(min(times[0], odom.stamps[0])), end=float(max(times[-1], odom.stamps[-1])),
                       skipped=dict(prism.skipped), warnings=warnings + prism.warnings, separate_clocks=True)

    def iter_images(self, topics: Optional[BagTopics] = None) -> Iterator[Tuple[float, np.ndarray]]:
        """``(time s, grey image)`` of each frame in order; a break in decoding raises VideoError (where)
        after the frames before it."""
        for _, t, image in video_frames(self.video, self.clock_start(), grey=True):
            yield t, image
