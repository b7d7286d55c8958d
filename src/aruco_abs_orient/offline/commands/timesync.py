"""``aruco-abs-orient timesync``: the camera/VO ↔ total-station time offset of a recording (the arguments).

In: the recording, optionally the marker map (the offset refined with the marker bearings) and a params file.
Out: the estimates of :func:`aruco_abs_orient.offline.sync.estimate_bag_offset` as lines for people (where the
VO heading gives none, why, and the marker bearings' scan), the plot with ``--plot`` and the ``calibrate``
command to run next. Exit status: 0 an offset, 1 none (no motion, too
short, a weak coherence peak: why), 2 bad input.
"""

from __future__ import annotations

import argparse

from ...errors import ConfigurationError, NoResultError
from ...markers import MarkerMap
from ...params import load_params
from ..commandlines import calibrate_command
from ..options import BAGS_HELP, add_params_option, add_topics, add_video_inputs, topics_from, video_recording

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "timesync", help="camera/VO ↔ total-station time offset of a recording",
        description="The camera/VO ↔ total-station time offset of a recording: phase coherence of "
                    "the VO yaw with the prism track's heading (the paper's cross-correlation printed beside "
                    "it); with --markers refined with the marker bearings (sub-millisecond where the VO "
                    "drifts; detects the markers in every N-th image, the slow part), and found with them alone "
                    "where the heading gives none (a drive at a constant turn rate).",
        epilog="examples:\n  aruco-abs-orient timesync run.bag --plot results/\n"
               "  aruco-abs-orient timesync run.bag --markers markers.yaml --every 3\n"
               "  aruco-abs-orient timesync run.bag --params my_params.yaml\n"
               "  aruco-abs-orient timesync --video run.mp4 --trajectory frame_trajectory.txt --trajectory-frame "
               "camera_optical --prism prism.gsi --lever-arms lever_arms.yaml",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bag", nargs="*", help="ROS 1 bag with /tf (odom→base_link) and the prism (and the images, "
                   "with --markers)" + BAGS_HELP)
    p.add_argument("--markers", metavar="YAML", help="marker map: refine the offset with the marker bearings")
    p.add_argument("--every", type=int, metavar="N",
                   help="with --markers: search every N-th image (default: about 10 a second, every 3rd at 30 fps)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--search", type=float, nargs=2, metavar=("MIN", "MAX"),
                   help="offsets searched, seconds (default -1 1 for a bag; for a video every offset at which the "
                        "trajectory and the prism log overlap by 10 s or more)")
    p.add_argument("--plot", metavar="DIR", help="write DIR/timesync.png (the offset and what it rests on: with "
                   "--markers the marker bearings' residual against the offset) and DIR/timesync.json (its curves)")
    p.add_argument("--min-confidence", type=float, default=0.3, metavar="C",
                   help="refuse an estimate whose confidence (0-1) is below C (default 0.3)")
    add_params_option(p, "timesync section (the estimate's smoothing, windows and limits) and, with --markers, "
                         "its detection section")
    add_topics(p)
    add_video_inputs(p)
    p.set_defaults(handler=run)
    return p


def run(a: argparse.Namespace) -> int:
    """``timesync``: 0 an offset printed (and the next command), 1 none, 2 bad input."""
    from ...timesync import TimeSyncError
    from ..sync import estimate_bag_offset

    if a.every is not None and a.every < 1:
        raise ConfigurationError(f"--every: expected an integer ≥ 1, got {a.every}")
    tunables = load_params(a.params)
    marker_map = MarkerMap.load(a.markers) if a.markers else None
    recording = video_recording(a, marker_map) or a.bag
    try:
        out = estimate_bag_offset(recording, topics_from(a), tuple(a.search) if a.search else None, plot_dir=a.plot,
                                  marker_map=marker_map, every=a.every, progress=not a.quiet, params=tunables)
    except TimeSyncError as e:
        raise NoResultError(f"no time offset: {e}") from None
    est, base = out["timesync"], out["timesync_baseline"]
    if "heading_refused" in out:
        print(f"the VO heading gives no time offset: {out['heading_refused']}")
        print(f"scanned with the marker bearings:               {1e3 * est.offset:+.1f} ms ± {1e3 * est.sigma:.1f} ms "
              f"(every {1e3 * est.sigma:.0f} ms over the search)")
    else:
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
        raise NoResultError(f"no time offset: confidence {est.confidence:.2f} < {a.min_confidence} (the coherence "
                            "peak is weak: record longer, with more turns of varying rate, or give --markers)")
    hint = "" if a.markers else "   (give your marker map)"
    print(f"use: {calibrate_command(recording, a.markers, est.offset, out['image_rate'])}{hint}")
    return 0
