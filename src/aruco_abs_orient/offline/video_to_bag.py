"""``aruco-abs-orient video-to-bag``: a video recording (video + VO trajectory + prism log) as a ROS 1 bag.

For users who want ``rosbag play`` (``postprocess.launch``, rviz): the package's topic layout
(doc/design.md §3, the same as ``aruco-abs-orient-synth`` writes) — ``/camera/image/compressed`` (JPEG at
``quality``, frame ``camera``), ``/tf`` (``odom → base_link`` at each frame), ``/tf_static`` (latched
``base_link → camera`` and ``base_link → prism``), ``/ms60/prism`` (PointStamped in ``map``). Written
with rosbags (no ROS needed), read by Noetic's rosbag.

Clocks: the bag has one. Frames and odometry are moved onto the total station's clock
(video time − ``time_offset``, the offset ``timesync`` printed), so that the bag is processed with
``--time-offset 0``; a bag's player needs increasing record times of one clock. Each message is
recorded at its header stamp. Frames are decoded, encoded and written one by one (memory stays flat),
the prism samples merged between them in time order. Frames without odometry (outside the
trajectory) are left out and counted; a video broken part-way ends the bag there (the frames before
are kept) and the reason is returned.
"""

from __future__ import annotations

import heapq
import os
import sys
import tempfile
import time
from typing import List, NamedTuple, Optional, Tuple

from ..errors import AbsOrientError, ConfigurationError
from .bagio import BagTopics
from .video import VideoRecording, video_frames

__all__ = ["VideoBagResult", "video_to_bag"]


class VideoBagResult(NamedTuple):
    path: str
    frames: int             # images written
    skipped: int            # frames without odometry
    prism_samples: int
    stopped: str            # why the video ended early ('' when it did not)
    seconds: float          # wall time


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def video_to_bag(recording: VideoRecording, out: str, time_offset: float = 0.0, quality: int = 90,
                 progress: bool = True, topics: Optional[BagTopics] = None) -> VideoBagResult:
    """Write ``recording`` as the bag ``out`` (atomically: complete or absent). ``time_offset`` (s): video
    clock = total-station clock + ``time_offset``; ``quality``: JPEG quality 1-100."""
    import cv2
    from rosbags.rosbag1 import Writer
    from tqdm import tqdm

    from ..synthetic.bag import TOPICS, Messages, make_typestore

    if not 1 <= quality <= 100:
        raise ConfigurationError(f"quality: expected 1-100, got {quality}")
    topics = topics or BagTopics()
    t_start = time.monotonic()
    data = recording.read_data(topics)
    store = make_typestore()
    msgs = Messages(store)
    names = {"/camera/image/compressed": topics.image, "/tf": topics.tf, "/tf_static": topics.tf_static,
             "/ms60/prism": topics.prism}
    directory = os.path.dirname(os.path.abspath(out))
    fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(out) + ".", suffix=".tmp", dir=directory)
    os.close(fd)
    os.unlink(tmp)  # rosbags' Writer refuses an existing file
    frames = skipped = 0
    stopped = ""
    pending: List[Tuple[float, int]] = [(float(t), i) for i, t in enumerate(data.prism_stamps)]
    heapq.heapify(pending)
    try:
        with Writer(tmp) as writer:
            conn = {topic: writer.add_connection(names[topic], typ, typestore=store,
                                                 latching=1 if topic == "/tf_static" else None)
                    for topic, typ in TOPICS.items()}

            def flush(until: float) -> None:
                while pending and pending[0][0] <= until:
                    t, i = heapq.heappop(pending)
                    writer.write(conn["/ms60/prism"], _ns(t), msgs.point(t, data.prism_positions[i]))

            t0 = min(data.odom.stamps[0] - time_offset, data.prism_stamps[0] if len(pending) else float("inf"))
            writer.write(conn["/tf_static"], _ns(t0), msgs.tf([
                msgs.transform(t0, topics.base_frame, topics.camera_frame, data.base_T_camera),
                msgs.transform(t0, topics.base_frame, topics.prism_frame, data.base_T_prism)]))
            bar = tqdm(total=data.image_count, desc="video-to-bag", unit="frame", file=sys.stderr,
                       disable=not progress, dynamic_ncols=True)
            with bar:
                try:
                    for _, t_video, image in video_frames(recording.video, recording.clock_start(), grey=False):
                        bar.update(1)
                        T, valid = data.odom.transforms_at(t_video)
                        if not bool(valid):
                            skipped += 1
                            continue
                        s = t_video - time_offset
                        flush(s)
                        ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
                        writer.write(conn["/tf"], _ns(s), msgs.tf([msgs.transform(s, topics.odom_frame,
                                                                                  topics.base_frame, T)]))
                        writer.write(conn["/camera/image/compressed"], _ns(s), msgs.image(s, jpeg.tobytes()))
                        frames += 1
                except AbsOrientError as e:  # a video broken part-way: the bag ends with its last good frame
                    stopped = str(e)
            flush(float("inf"))
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return VideoBagResult(out, frames, skipped, len(data.prism_stamps), stopped, time.monotonic() - t_start)
