"""The abs_orient node's bookkeeping without ROS: at which stamp map→odom goes out, and the node's health.

The node's control (``nodecontrol.py``, called by ``ros/abs_orient_node.py``) uses these; nothing imports rospy, so
the policy is unit-tested with plain numbers (``test/unit/test_nodestate.py``). Times are float seconds
on the ROS clock of the messages (sim time during a bag replay); wall-clock durations are named so.

Stamp policy (:class:`MapOdomStamps`), doc/design.md §3 and doc/ros_api.md "map → odom":

- map→odom estimated at time ``t`` (an image's time, or the newest odometry stamp when it is re-published)
  is sent stamped ``t + tolerance`` (``~transform_tolerance``, as amcl's ``transform_tolerance``): a
  consumer looking up ``map → base_link`` at "now" or at a sensor's stamp finds it although the camera
  frame arrived 30–60 ms late. Safe because map→odom changes slowly (VO drift, a fraction of a degree a
  minute) and the value sent is the filter's estimate, which predicts it.
- The stamps sent only go forward: a stamp at or before the newest one sent is never sent (tf2 drops a
  repeated stamp as TF_REPEATED_DATA, and an older one would change what a consumer has already read
  for a time it looked up: an OLDER map→odom for the same time). A frame that arrives so late that its
  stamp would go back (images 0.5 s late, a replay faster than the node) still corrects the filter; the
  correction goes out at the next stamp after the newest sent (``republish(..., due_now=True)``).
- Re-publication: when the newest odometry stamp ``s`` gives ``s + tolerance`` at least one period
  (``1/~tf_rate``) past the newest stamp sent, the filter's prediction at ``s`` is sent at
  ``s + tolerance``: the stamps advance with the odometry while no image is processed.
- A stamp of the inputs going back by more than ``jump_tolerance`` (a bag looped or restarted, the clock
  set back) is a clock jump: the node resets, and so does the policy (the new timeline starts afresh).

The state file (:func:`state_path`, :func:`state_record`, :func:`state_snapshot`): one per node name and
master, and a state is restored only by the node, master and ``/run_id`` that wrote it (a respawn), never by
another replay or robot sharing the directory.

Live time offset (:func:`live_offset_to_apply`): a confident live estimate that contradicts the offset in
use replaces it, unless the marker yaws (the rolling self-check) support the offset in use and contradict
the estimate.
"""

from __future__ import annotations

import collections
import math
import os
import re
from typing import Deque, Dict, Iterable, List, NamedTuple, Optional, Tuple

import numpy as np

from .errors import ConfigurationError
from .transforms import make_T, rot_z, wrap_angle, yaw_of

__all__ = ["MapOdomStamps", "MapOdomPrediction", "NodeHealth", "NodeSnapshot", "IMAGE_OK", "IMAGE_JUMPED_BACK",
           "IMAGE_NOT_AFTER", "live_offset_to_apply", "state_path", "state_record", "state_snapshot"]

IMAGE_OK = "ok"
IMAGE_JUMPED_BACK = "jumped back"
IMAGE_NOT_AFTER = "not after the previous one"


def state_path(path: str, node_name: str, master_uri: str) -> str:
    """``path`` (``~state_file``) with the node's name and the master's port before its extension:
    ``~/.ros/abs_orient_state.json`` of ``/robot1/abs_orient`` on ``http://localhost:11311/`` →
    ``~/.ros/abs_orient_state.robot1.abs_orient.11311.json``; '' stays '' (no state file)."""
    if not path:
        return ""
    root, ext = os.path.splitext(path)
    port = master_uri.rstrip("/").rsplit(":", 1)[-1] if ":" in master_uri else "master"
    name = re.sub(r"[^A-Za-z0-9_-]+", ".", node_name).strip(".") or "node"
    return f"{root}.{name}.{port if port.isdigit() else 'master'}{ext or '.json'}"


def state_record(snapshot: Dict[str, object], writer: Dict[str, str]) -> Dict[str, object]:
    """What the state file holds: the filter's ``snapshot`` and its ``writer`` (node name, master URI, run id)."""
    return {"writer": dict(writer), "filter": snapshot}


def state_snapshot(record, writer: Dict[str, str]) -> Tuple[Optional[Dict[str, object]], str]:
    """(the filter's snapshot, '') of a state file's ``record`` written by ``writer`` (this node), or (None, why
    not): another node, master or run wrote it (a state from another replay or robot is never restored)."""
    if not isinstance(record, dict) or not isinstance(record.get("writer"), dict) or "filter" not in record:
        return None, "not a state of this version (no writer)"
    theirs = record["writer"]
    for key, what in (("node", "node"), ("master", "master"), ("run_id", "run (roscore /run_id)")):
        if str(theirs.get(key)) != str(writer.get(key)):
            return None, f"written by another {what}: {theirs.get(key)!r}, not {writer.get(key)!r}"
    return record["filter"], ""


def live_offset_to_apply(in_use: float, estimator, selfcheck) -> Tuple[Optional[float], bool]:
    """The live time-offset estimate to switch to (s; None: keep ``in_use``), and whether the marker yaws
    vetoed one. ``estimator``: an ``OnlineOffsetEstimator`` (its ``suggestion``: a confident estimate that
    contradicts ``in_use``); ``selfcheck``: a ``RollingSelfCheck`` (its ``supports``: the marker yaws of its
    last check agree with an offset). The estimate comes from headings of travel, which a platform that
    wanders sideways biases (the realistic demo: 316.7 ± 9.5 ms, truth 367 ms); the self-check fits the
    marker yaws' residuals against their bearing rates (there 368.1 ± 0.3 ms): when it supports ``in_use``
    and contradicts the estimate, ``in_use`` stays."""
    better = estimator.suggestion(in_use)
    if better is None:
        return None, False
    if selfcheck.supports(in_use) and not selfcheck.supports(better):
        return None, True
    return better, False


class MapOdomStamps:
    """When and at which stamp map→odom is sent (see the module's doc).

    ``tolerance`` s (≥ 0): future-dating; ``period`` s (> 0): re-publication period while no image is
    processed; ``jump_tolerance`` s (> 0): an input stamp going back by more than this is a clock jump.
    """

    def __init__(self, tolerance: float, period: float, jump_tolerance: float):
        if not (math.isfinite(tolerance) and tolerance >= 0):
            raise ConfigurationError(f"transform tolerance: expected a finite number ≥ 0 s, got {tolerance!r}")
        if not (math.isfinite(period) and period > 0):
            raise ConfigurationError(f"re-publication period: expected a positive number of s, got {period!r}")
        if not (math.isfinite(jump_tolerance) and jump_tolerance > 0):
            raise ConfigurationError(f"time jump tolerance: expected a positive number of s, got {jump_tolerance!r}")
        self.tolerance = float(tolerance)
        self.period = float(period)
        self.jump_tolerance = float(jump_tolerance)
        self.held_back = 0          # frames whose stamp would have gone back: sent later, at a newer stamp
        self.reset()

    def reset(self) -> None:
        """Forget the timeline (after a clock jump)."""
        self.last_image: Optional[float] = None   # s, newest image stamp taken
        self.last_sent: Optional[float] = None    # s, newest map→odom stamp sent (future-dated)
        self.pending = False                      # a held-back correction waits for a newer stamp

    def check_image(self, t: float) -> str:
        """Classify an image stamp ``t`` (s): IMAGE_OK (taken: it is the newest), IMAGE_JUMPED_BACK (by
        more than ``jump_tolerance``: reset the node, then call again) or IMAGE_NOT_AFTER (a stamp at or
        before the previous image's, within the tolerance: skip the frame)."""
        if self.last_image is not None:
            if t < self.last_image - self.jump_tolerance:
                return IMAGE_JUMPED_BACK
            if t <= self.last_image:
                return IMAGE_NOT_AFTER
        self.last_image = t
        return IMAGE_OK

    def jumped_back(self, newest: Optional[float], t: float) -> bool:
        """Did another input's stamp go from ``newest`` (s, None: none yet) back to ``t`` by more than the
        jump tolerance (a prism stamp, say)?"""
        return newest is not None and t < newest - self.jump_tolerance

    def for_estimate(self, t: float) -> Optional[float]:
        """The stamp for map→odom estimated at time ``t`` (an image's): ``t + tolerance``, or None when that
        is not after the newest stamp sent (held back: the next ``republish`` sends the correction)."""
        stamp = t + self.tolerance
        if self.last_sent is not None and stamp <= self.last_sent:
            self.held_back += 1
            self.pending = True
            return None
        self._sent(stamp)
        return stamp

    def republish(self, newest_odometry: float) -> Optional[float]:
        """The stamp for the filter's prediction at ``newest_odometry`` (s), or None when none is due: due
        when ``newest_odometry + tolerance`` is a period past the newest stamp sent, or merely after it
        while a held-back correction is pending (or when nothing was sent yet)."""
        stamp = newest_odometry + self.tolerance
        if self.last_sent is not None and (
                stamp <= self.last_sent or (not self.pending and stamp < self.last_sent + self.period)):
            return None
        self._sent(stamp)
        return stamp

    def _sent(self, stamp: float) -> None:
        self.last_sent = stamp
        self.pending = False


class MapOdomPrediction:
    """The filter's map→odom prediction as a function of time, for a thread that must not wait for the filter.

    The map→odom filter (``correction``) predicts its state linearly in time (yaw offset plus a drift rate,
    a translation), so two of its predictions, ``map_T_odom_0`` at ``t0`` and ``map_T_odom_1`` at ``t1``
    (4×4, rotations about z, s), give every other one: yaw and translation interpolated or extrapolated
    linearly. The node's re-publication timer uses it while the image thread holds the filter.
    """

    def __init__(self, t0: float, map_T_odom_0: np.ndarray, t1: float, map_T_odom_1: np.ndarray,
                 yaw_variances: Tuple[float, float] = (math.nan, math.nan)):
        if not t1 > t0:
            raise ConfigurationError(f"map->odom prediction: t1 ({t1}) must be after t0 ({t0})")
        A, B = np.asarray(map_T_odom_0, dtype=float), np.asarray(map_T_odom_1, dtype=float)
        self.t0 = float(t0)
        self.yaw0 = float(yaw_of(A[:3, :3]))
        self.p0 = A[:3, 3].copy()
        self.yaw_rate = float(wrap_angle(yaw_of(B[:3, :3]) - self.yaw0)) / (t1 - t0)   # rad/s
        self.p_rate = (B[:3, 3] - self.p0) / (t1 - t0)                                  # m/s
        self.var0 = float(yaw_variances[0])                                              # rad², the yaw's
        self.var_rate = (float(yaw_variances[1]) - self.var0) / (t1 - t0)               # rad²/s

    def yaw_variance(self, t: float) -> float:
        """The variance (rad²) of the predicted yaw at time ``t`` (s); NaN when not given; never below t0's."""
        return self.var0 + self.var_rate * max(0.0, float(t) - self.t0)

    def at(self, t: float) -> np.ndarray:
        """map→odom (4×4) predicted at time ``t`` (s)."""
        dt = float(t) - self.t0
        return make_T(rot_z(self.yaw0 + self.yaw_rate * dt), self.p0 + self.p_rate * dt)


# ------------------------------------------------------------------------------------------------ health
_PROBLEM_TEXTS = (("bad_images", "corrupt images"), ("tf_failures", "tf lookups failed"), ("tf_nan", "NaN in tf"),
                  ("frame_errors", "frame errors"), ("unknown_ids", "unknown ids"),
                  ("bad_prism", "bad prism messages"), ("pipeline_exceptions", "pipeline failures"),
                  ("bad_params", "reconfigured parameters refused"), ("resets", "time jumped back: reset"),
                  ("state_file", "state file writes failed"))
"""Counters that make the node's status WARN when they grew since the last report, with their text."""


class NodeSnapshot(NamedTuple):
    """What the node hands :meth:`NodeHealth.report`: ``initialised`` (the filter); ``image_age_wall`` s (wall)
    since the last image; ``last_prism_stamp`` s (ROS time, None: none yet); ``prisms_waiting``: prisms arrived
    but wait for the pipeline; ``images_received``, ``images_dropped`` (counts); ``time_offset`` s and
    ``time_offset_source``; ``pipeline`` an ``AbsOrientPipeline`` (None before the static tfs);
    ``offset_estimator`` an ``OnlineOffsetEstimator`` or None; ``map_odom_yaw`` rad (None: no filter yet)."""

    initialised: bool
    image_age_wall: float
    last_prism_stamp: Optional[float]
    prisms_waiting: bool
    images_received: int
    images_dropped: int
    time_offset: float
    time_offset_source: str
    pipeline: object = None
    offset_estimator: object = None
    map_odom_yaw: Optional[float] = None


class NodeHealth:
    """The node's counters and what they mean: the ``pipeline`` status of /diagnostics.

    The node counts (``count``/``error``), records latencies, stage times and the ids seen; ``report``
    turns them into (level, message, values) from what happened since the previous report, so the status
    recovers as soon as the input is good again. ``extra_values`` (name → callable returning a value) lets
    a node add a key in one line (``health.extra_values["tilt source"] = lambda: ...``).
    """

    def __init__(self, image_timeout: float, prism_timeout: float, publish_tf: bool, start_wall: float,
                 frames: Tuple[str, str, str] = ("base_link", "camera", "prism")):
        self.image_timeout = float(image_timeout)     # s (wall)
        self.prism_timeout = float(prism_timeout)     # s (ROS time)
        self.publish_tf = bool(publish_tf)
        self.frames = frames                          # base, camera, prism frame names (for messages)
        self.counts: Dict[str, int] = collections.Counter()
        self.last_error = ""
        self.latencies_ms: Deque[float] = collections.deque(maxlen=600)
        self.stage_ms: Dict[str, float] = {}          # ms per stage summed since the last report
        self.seen_ids: Tuple[int, ...] = ()
        self.extra_values: Dict[str, object] = {}
        self._prev: Dict[str, int] = {}
        self._prev_images = (0, 0)                    # images received, dropped at the previous report
        self._prev_wall = float(start_wall)           # s (monotonic) of the previous report

    def count(self, key: str, n: int = 1) -> None:
        self.counts[key] += n

    def error(self, key: str, text: str) -> int:
        """Count a problem under ``key`` and keep ``text`` as the last error; returns the count so far."""
        self.counts[key] += 1
        self.last_error = text
        return self.counts[key]

    def add_stages(self, timings: Dict[str, float]) -> None:
        for stage, ms in timings.items():
            self.stage_ms[stage] = self.stage_ms.get(stage, 0.0) + float(ms)

    def set_seen(self, ids: Iterable[int]) -> bool:
        """The accepted ids of the newest frame; True when they changed."""
        seen = tuple(sorted({int(i) for i in ids}))
        changed = seen != self.seen_ids
        self.seen_ids = seen
        return changed

    def report(self, now_wall: float, now_ros: float, node: NodeSnapshot) -> Tuple[str, str, Dict[str, object]]:
        """(level 'ok'|'warn'|'error', message, values) since the previous report, which this one ends.

        ``now_wall`` s monotonic, ``now_ros`` s ROS time; ``node`` the node's state (:class:`NodeSnapshot`).
        """
        delta = {k: v - self._prev.get(k, 0) for k, v in self.counts.items()}
        prism_age = now_ros - node.last_prism_stamp if node.last_prism_stamp is not None else math.inf
        values = self._values(now_wall, node, delta, prism_age)
        level, problems = self._problems(node, delta, prism_age, values["rate [Hz]"])
        message = "; ".join(problems) if problems else f"tracking {len(self.seen_ids)} marker(s)"
        self._prev = dict(self.counts)
        self._prev_images = (node.images_received, node.images_dropped)
        self._prev_wall = now_wall
        self.stage_ms.clear()
        return level, message, values

    def _values(self, now_wall: float, node: NodeSnapshot, delta: Dict[str, int],
                prism_age: float) -> Dict[str, object]:
        """The status's key/values: counters, rates, latencies, the time offset, the filter's, the stage times."""
        images_received, images_dropped = node.images_received, node.images_dropped
        dt = max(now_wall - self._prev_wall, 1e-6)
        lat = np.array(self.latencies_ms) if self.latencies_ms else np.array([np.nan])
        values: Dict[str, object] = {
            "initialised": node.initialised,
            "markers seen": len(self.seen_ids),
            "marker ids": " ".join(str(i) for i in self.seen_ids) or "-",
            "rate [Hz]": delta.get("processed", 0) / dt,
            "images received": images_received,
            "images processed": self.counts["processed"],
            "images dropped": images_dropped,
            "dropped fraction": images_dropped / images_received if images_received else 0.0,
            "latency median [ms]": float(np.median(lat)),
            "latency p95 [ms]": float(np.percentile(lat, 95)),
            "time offset [s]": node.time_offset,
            "time offset source": node.time_offset_source,
            "prism age [s]": prism_age,
            "frames with marker yaw": self.counts["frames_with_yaw"],
            "unknown marker ids": self.counts["unknown_ids"],
            "tf failures": self.counts["tf_failures"],
            "tf NaN": self.counts["tf_nan"],
            "bad images": self.counts["bad_images"],
            "frame errors": self.counts["frame_errors"],
            "pipeline failures": self.counts["pipeline_exceptions"],
            "parameters refused": self.counts["bad_params"],
            "resets": self.counts["resets"],
            "publish_tf": self.publish_tf,
            "map->odom sent": self.counts["tf_published"],
            "map->odom held back": self.counts["tf_held_back"],
            "last error": self.last_error or "-",
        }
        offset_estimator, pipeline = node.offset_estimator, node.pipeline
        if offset_estimator is not None:
            latest = offset_estimator.latest
            values["time offset estimate [s]"] = latest.offset if latest is not None else "-"
            values["time offset estimate sigma [ms]"] = 1e3 * latest.sigma if latest is not None else "-"
            values["time offset estimate confidence"] = latest.confidence if latest is not None else "-"
            values["time offset estimate note"] = offset_estimator.last_error or "-"
            values["time offset estimate refused"] = self.counts["time_offset_switch_refused"]
        if node.map_odom_yaw is not None:
            values["map->odom yaw [deg]"] = math.degrees(float(node.map_odom_yaw))
        n = max(delta.get("processed", 0), 1)
        for stage, ms in self.stage_ms.items():
            values[f"stage {stage} [ms]"] = ms / n
        if pipeline is not None:
            for k, v in sorted(pipeline.stats.items()):
                values["pipeline " + k] = v
            fs = pipeline.filter.stats
            values["filter waiting reason"] = pipeline.waiting_reason or "-"
            values["filter lock-out recoveries"] = fs.lockout_recoveries
            values["filter re-initialisations"] = fs.reinitialisations
            values["filter yaw noise scale"] = fs.noise_scale
            values["filter restored from a state [s old]"] = fs.restored_age if math.isfinite(fs.restored_age) else "-"
        for key, get in self.extra_values.items():
            values[key] = get()
        return values

    def _problems(self, node: NodeSnapshot, delta: Dict[str, int], prism_age: float,
                  rate: float) -> Tuple[str, List[str]]:
        """The status's level and its problems since the previous report (``rate`` Hz: images processed)."""
        base, camera, prism = self.frames
        pipeline, images_received, images_dropped = node.pipeline, node.images_received, node.images_dropped
        problems: List[str] = []
        level = "ok"
        if pipeline is None and delta.get("no_static_tf", 0):
            level = "error"
            problems.append(f"no static tf {base} -> {camera}/{prism}")
        if node.image_age_wall > self.image_timeout:
            problems.append(f"no image for {node.image_age_wall:.1f} s")
        if prism_age > self.prism_timeout:
            waiting = "prisms arrive, waiting for the first image" if node.prisms_waiting else "no prism yet"
            problems.append(waiting if math.isinf(prism_age) else f"no prism for {prism_age:.1f} s")
        for key, text in _PROBLEM_TEXTS:
            if delta.get(key, 0):
                problems.append(f"{delta[key]} {text}")
        dropped = images_dropped - self._prev_images[1]
        if dropped > 0:  # the oldest images went: say what the node achieves
            problems.append(f"cannot keep up: {dropped} of {images_received - self._prev_images[0]} images dropped "
                            f"(the oldest), processing {rate:.1f} Hz")
        if problems and level == "ok":
            level = "warn"
        if not problems and not node.initialised:
            level = "warn"
            why = pipeline.waiting_reason if pipeline is not None else "waiting for the static tfs"
            problems.append(f"initialising: {why}")
        return level, problems
