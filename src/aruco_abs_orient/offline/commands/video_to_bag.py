"""``aruco-abs-orient video-to-bag``: a video recording as a ROS 1 bag for rosbag play (the arguments).

In: the video, its VO trajectory, the prism log and the lever arms (the options of
:func:`~aruco_abs_orient.offline.options.add_video_inputs`), the time offset, the JPEG quality. Out: the bag of
:func:`aruco_abs_orient.offline.video_to_bag.video_to_bag` and one line saying what it holds; warnings for
frames left out. Exit status: 0 written, 1 no frame, 2 bad input.
"""

from __future__ import annotations

import argparse
import os
import sys

from ...errors import ConfigurationError
from ...markers import MarkerMap
from ..options import add_topics, add_video_inputs, output_directory, topics_from, video_recording

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
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
    add_topics(p)
    add_video_inputs(p)
    p.set_defaults(handler=run)
    return p


def run(a: argparse.Namespace) -> int:
    """``video-to-bag``: 0 the bag written, 1 no frame in it, 2 bad input."""
    from ..video_to_bag import video_to_bag

    if not 1 <= a.quality <= 100:
        raise ConfigurationError(f"--quality: expected 1-100, got {a.quality}")
    output_directory(os.path.dirname(os.path.abspath(a.out)), a.out)
    a.bag = None
    recording = video_recording(a, MarkerMap.load(a.markers) if a.markers else None)  # raises without --video
    r = video_to_bag(recording, a.out, a.time_offset, a.quality, progress=not a.quiet, topics=topics_from(a))
    print(f"wrote {r.path}: {r.frames} images (JPEG quality {a.quality}), {r.prism_samples} prism samples, "
          f"{os.path.getsize(r.path) / 1e6:.1f} MB in {r.seconds:.1f} s; process it with --time-offset 0")
    if r.skipped:
        print(f"aruco-abs-orient: warning: {r.skipped} frame(s) outside the trajectory left out", file=sys.stderr)
    if r.stopped:
        print(f"aruco-abs-orient: warning: {r.stopped}", file=sys.stderr)
    return 0 if r.frames else 1

