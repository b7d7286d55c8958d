"""The overview picture of a processed run (``evaluate --overview``): what the camera saw, and where.

In: a run's directory (``process``'s summary.json, trajectory.tum, observations.csv), the bag or video it came
from, the marker map and optionally a reference TUM file. Out: ``overview.png``: the 360° frame in which the
pipeline saw the most markers (a video's middle frame) with the markers a search of the whole frame found
outlined, the map's markers where the run's pose puts them (each one not found or not used marked with why),
and below it the trajectory of base_link (and the reference), its heading, the markers and where the frame was
taken. Its title answers how many of the map's markers were found and used.
"""

from __future__ import annotations

import os
from collections import Counter
from typing import Dict, Optional

import numpy as np

from .. import plots
from ..transforms import yaw_of
from ..tum import read_tum
from .evaluate import EvaluateError, read_observations, read_summary

__all__ = ["overview_figure"]


def _overview_answer(found, expected, when: Optional[float]) -> str:
    """The overview's title: how many of the map's markers were found and used in the frame (at ``when`` s since
    the start; None: a video's middle frame), and why not the others (grouped by their reason)."""
    markers = f"{len(found)} marker{'s' if len(found) != 1 else ''}"
    if when is None:
        return (f"{markers} found in the middle frame of the video (where the map's markers should be is drawn for "
                "bags: their lever arms are in the bag)")
    if not expected:
        return f"{markers} found in this frame ({when:.1f} s); no pose then, so where the map's markers should be is " \
               "not drawn"
    ok = [e for e in expected if e.status == "found"]
    text = f"{len(ok)} of the map's {len(expected)} markers found and used in this frame ({when:.1f} s)"
    odd = [f"marker {e.id} {e.status}" for e in expected if e.status != "found" and e.status.startswith("found")]
    missed = Counter(e.status.split(" (")[0] for e in expected if not e.status.startswith("found"))
    parts = odd + [f"{n} {why}" for why, n in missed.most_common()]
    return text + ("; " + "; ".join(parts) if parts else "")


def _busiest_stamp(rows: Optional[Dict[str, np.ndarray]], poses) -> Optional[float]:
    """The total-station time of the image whose markers the pipeline saw most of (with a pose; the one nearest
    the middle of the run among equals), or None without observations."""
    if rows is None or not len(rows["time"]) or not len(poses):
        return None
    times, counts = np.unique(rows["time"], return_counts=True)
    keep = (times >= poses[0]) & (times <= poses[-1])
    if not np.any(keep):
        return None
    times, counts = times[keep], counts[keep]
    middle = 0.5 * (poses[0] + poses[-1])
    best = np.lexsort((np.abs(times - middle), -counts))[0]
    return float(times[best])


def overview_figure(path: str, bag: str, run_dir: str, reference: Optional[str], marker_map, topics=None) -> str:
    """One picture of a run (the README's): a 360° frame of the bag (the one in which the pipeline saw the most
    markers; of a video, ``bag`` with a video file's extension: the middle one) with the markers a search of
    the whole frame found outlined, and the map's markers where the run's pose puts them, each one not found
    or not used marked with why (:func:`aruco_abs_orient.debugview.expected_markers`); below, the corrected
    trajectory of base_link vs the reference (when given), with its absolute heading, the markers and where
    the frame was taken, in the trajectory's coordinates (full ones with a map origin). Returns ``path``."""
    from ..debugview import expected_markers
    from ..detection import decode_jpeg
    from ..tracking import MarkerTracker
    from .bagio import BagTopics, iter_images, open_reader, read_bag_data
    from .video import VIDEO_EXTENSIONS, video_frames, video_summary

    topics = topics or BagTopics()
    summary = read_summary(run_dir)
    offset = float(summary.get("time_offset_s", 0.0))
    est = read_tum(os.path.join(run_dir, "trajectory.tum"))
    obs_path = os.path.join(run_dir, "observations.csv")
    rows = read_observations(obs_path, every_row=True) if os.path.exists(obs_path) else None
    grey, stamp = None, None
    if os.path.splitext(bag)[1].lower() in VIDEO_EXTENSIONS:
        middle = video_summary(bag)[0] // 2
        video = video_frames(bag)
        grey = next((image for k, _, image in video if k >= middle), None)
        video.close()
    else:
        busiest = _busiest_stamp(rows, est.stamps)
        reader = open_reader(bag)
        middle = sum(c.msgcount for c in reader.connections if c.topic == topics.image) // 2
        reader.close()
        frames = iter_images(bag, topics)
        for i, (t, payload) in enumerate(frames):
            wanted = i >= middle if busiest is None else t - offset >= busiest - 1e-4
            if wanted and isinstance(payload, bytes):
                grey, stamp = decode_jpeg(payload), t
                break
        frames.close()
    if grey is None:
        raise EvaluateError(f"{bag}: no decodable image from the middle of the bag on")
    found = MarkerTracker(marker_map).process(grey).observations
    expected, where, when = [], None, None
    t0 = float(summary.get("recording_start_s", est.stamps[0] if len(est.stamps) else 0.0))
    if stamp is not None:
        t = stamp - offset
        when = t - t0
        T, valid = est.transforms_at(t) if len(est.stamps) else (None, False)
        if bool(valid):
            where = T[:2, 3].copy()
            T[:3, 3] -= marker_map.to_full(np.zeros(3))          # full coordinates back to the map's
            map_T_camera = T @ read_bag_data(bag, topics).base_T_camera
            near = np.abs(rows["time"] - t) < 1e-4 if rows is not None else np.zeros(0, dtype=bool)
            used = {int(i): ("" if a else r) for i, a, r in zip(rows["id"][near], rows["accepted"][near],
                                                                 rows["reason"][near])} if rows is not None else {}
            expected = expected_markers(marker_map, map_T_camera, grey.shape[1], {o.id: o.centre for o in found},
                                        used)
    ref_xy = read_tum(reference).positions[:, :2] if reference else None
    marker_xy = {m.id: marker_map.to_full(m.position)[:2] for m in marker_map}
    return plots.plot_overview(path, grey, found, expected, (est.positions[:, :2], yaw_of(est.rotations)),
                               marker_xy, where, ref_xy, _overview_answer(found, expected, when))
