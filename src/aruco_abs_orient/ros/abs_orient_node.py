"""The ``abs_orient`` node: marker bearings in 360° images → tf ``map → odom`` and absolute inputs for
robot_localization (DESIGN §3). A thin shell around :class:`aruco_abs_orient.pipeline.AbsOrientPipeline`.

Inputs: ``camera/image/compressed`` (``sensor_msgs/CompressedImage``) or, with ``~image_transport: raw``,
``camera/image`` (``sensor_msgs/Image``); ``ms60/prism`` (``geometry_msgs/PointStamped`` in map); tf
``odom → base_link`` (looked up at each image stamp) and the static lever arms ``base_link → camera``,
``base_link → prism``; the marker map YAML ``~markers``.

Outputs (all stamped with the IMAGE's header stamp, the clock of the odometry they go with):
- tf ``map → odom`` (``~publish_tf``, default true; false when a robot_localization EKF in map mode owns
  it — never two owners);
- ``abs_orient/orientation`` (``PoseWithCovarianceStamped``): the frame's yaw fused from its markers
  alone (``FrameResult.fused_yaw``: a measurement, independent of the odometry's yaw, unlike the filtered
  ``yaw``), roll/pitch from odometry, unobserved parts at variance 1e6; only when the node's filter
  accepted it (its gate drops false ids);
- ``abs_orient/prism_pose`` (``PoseWithCovarianceStamped``): base_link's position from the prism, lever
  arm removed; ``abs_orient/pose`` (``PoseStamped``): the corrected pose; ``abs_orient/detections``;
  ``abs_orient/markers`` (rviz ``MarkerArray``, latched); ``/diagnostics``.

Time. ``~time_offset`` (s): camera stamps = true (total-station) time + offset; the pipeline works in
total-station time (``stamp − offset``), the published messages keep the image stamp. ``map → odom`` is
stamped at the image time (every processed frame once the filter is initialised), never future-dated.
When the newest ``odom → base_link`` stamp in the tf buffer is ``1/~tf_rate`` s past the newest map→odom
sent (no marker seen, camera stalled, frames dropped, images slower than tf_rate), map→odom is
re-published AT THAT ODOMETRY STAMP with the filter's prediction there: the stamp advances with the
odometry, never beyond it. A stamp already sent is never sent again (tf2 drops a repeated stamp of an
edge as TF_REPEATED_DATA); an image-time value a little older than a re-published one is still sent
(tf2 inserts out-of-order stamps within its cache), so no measurement is lost. A stamp going back by
more than ``~time_jump_tolerance`` s (sim time: a bag looped or restarted) resets the pipeline and
clears the tf buffer.

Real time. The image callback only drops the message into a one-slot mailbox (the newest wins; a
replaced, unprocessed image is counted as dropped); the main thread processes the mailbox. Subscriber
``queue_size=1`` with a large ``buff_size``: no queue can grow. Prism messages go through a bounded deque.

Bad input never stops the node: a corrupt image, unknown ids, NaN/missing tf, no prism — each is counted,
logged (throttled) and reported on ``/diagnostics``, and processing carries on with the next message. A
marker map that does not load → one line (``[FATAL] ... abs_orient: <file>: <field>: <problem>``) and exit
status 2.
"""

from __future__ import annotations

import collections
import json
import math
import os
import sys
import threading
import time
import traceback
from dataclasses import dataclass, fields
from functools import cached_property
from typing import Deque, Dict, Optional, Tuple

import numpy as np

from ..calibration import CalibrationError, load_calibration
from ..errors import ConfigurationError
from ..markers import MarkerMap, MarkerMapError
from ..pipeline import AbsOrientPipeline, FrameResult, PipelineError, all_param_fields
from ..selfcheck import RollingSelfCheck
from ..timesync import OnlineOffsetEstimator
from ..transforms import yaw_of
from ..tum import atomic_write_text

__all__ = ["NodeConfig", "NodeConfigError", "Mailbox", "AbsOrientNode", "main"]

RECONFIGURABLE_NODE_PARAMS = ("time_offset",)
"""Node-level entries of cfg/AbsOrient.cfg (all others are pipeline tunables, see all_param_fields)."""


class NodeConfigError(ConfigurationError, ValueError):
    """A node parameter with a bad value: names the parameter."""


@dataclass
class NodeConfig:
    """Private parameters of the node (names without ``~``); units in the names' docs.

    - ``markers``: marker map YAML path (required).
    - ``image_transport``: 'compressed' (``camera/image/compressed``) or 'raw' (``camera/image``).
    - ``time_offset``: s, camera stamps = true time + offset.
    - ``estimate_time_offset``: estimate the offset live (``timesync.OnlineOffsetEstimator``: VO yaw and
      marker yaws against the prism track's heading, in a background thread), shown in diagnostics.
    - ``apply_estimated_time_offset``: use a confident live estimate when it contradicts the offset in
      use (by more than 5 σ and 20 ms: a forgotten or wrong offset); a good offset is never replaced by
      a coarser one.
    - ``calibration``: calibration YAML of ``aruco-abs-orient calibrate`` whose lever arms replace the
      static tfs ``base_link → camera/prism`` (a bag replayed with its uncalibrated /tf_static); empty:
      the lever arms come from tf.
    - ``publish_tf``: broadcast ``map → odom`` (false when an EKF owns it).
    - ``tf_rate``: Hz, re-publication rate of ``map → odom`` while no image is processed.
    - ``tf_timeout``: s (wall clock), how long to wait for ``odom → base_link`` at an image stamp.
    - ``time_jump_tolerance``: s, a stamp going back by more than this resets the node.
    - ``prism_timeout``: s, prism older than this → diagnostics warn.
    - ``image_timeout``: s (wall clock), no image for this long → diagnostics warn.
    - ``diagnostics_rate``: Hz.
    - ``state_file``: JSON file where the map→odom filter's state is kept (written at most once a second);
      a node (re)started within ``state_max_age`` s of it starts from it and publishes map→odom at once.
      Empty: none.
    - ``state_max_age``: s, oldest state restored (in ROS time: a bag replayed later never matches).
    - frames: ``map_frame``, ``odom_frame``, ``base_frame``, ``camera_frame``, ``prism_frame``.
    """

    markers: str = ""
    image_transport: str = "compressed"
    time_offset: float = 0.0
    estimate_time_offset: bool = True
    apply_estimated_time_offset: bool = True
    calibration: str = ""
    publish_tf: bool = True
    tf_rate: float = 20.0
    tf_timeout: float = 0.05
    time_jump_tolerance: float = 0.5
    prism_timeout: float = 1.0
    image_timeout: float = 2.0
    diagnostics_rate: float = 1.0
    state_file: str = ""
    state_max_age: float = 10.0
    map_frame: str = "map"
    odom_frame: str = "odom"
    base_frame: str = "base_link"
    camera_frame: str = "camera"
    prism_frame: str = "prism"

    @classmethod
    def from_params(cls, get_param) -> NodeConfig:
        """Read ``~name`` for every field through ``get_param(name, default)`` (rospy.get_param) and
        validate. Raises NodeConfigError naming the parameter."""
        kw = {}
        for f in fields(cls):
            default = f.default
            value = get_param("~" + f.name, default)
            if isinstance(default, bool):
                if not isinstance(value, bool):
                    raise NodeConfigError(f"~{f.name}: expected true or false, got {value!r}")
            elif isinstance(default, float):
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                    raise NodeConfigError(f"~{f.name}: expected a number, got {value!r}")
                value = float(value)
            elif not isinstance(value, str):
                raise NodeConfigError(f"~{f.name}: expected a string, got {value!r}")
            kw[f.name] = value
        config = cls(**kw)
        if not config.markers:
            raise NodeConfigError("~markers: no marker map given (a YAML file, see cfg/markers_example.yaml)")
        config.calibrated_lever_arms()  # read here, once: a file that does not load is one clear line at start-up
        if config.image_transport not in ("compressed", "raw"):
            raise NodeConfigError(f"~image_transport: expected 'compressed' or 'raw', got {config.image_transport!r}")
        for name in ("tf_rate", "diagnostics_rate", "tf_timeout", "time_jump_tolerance", "prism_timeout",
                     "image_timeout", "state_max_age"):
            if getattr(config, name) <= 0:
                raise NodeConfigError(f"~{name}: expected a positive number, got {getattr(config, name)!r}")
        return config

    def calibrated_lever_arms(self) -> Optional[Dict[str, np.ndarray]]:
        """``{"camera": base_T_camera, "prism": base_T_prism}`` of ``calibration`` (None without one),
        read from the file on the first call only. Raises NodeConfigError naming the file and the key."""
        return self._calibrated_lever_arms

    @cached_property
    def _calibrated_lever_arms(self) -> Optional[Dict[str, np.ndarray]]:
        if not self.calibration:
            return None
        try:
            return load_calibration(self.calibration)
        except CalibrationError as e:
            raise NodeConfigError(f"~calibration: {e}") from None


class Mailbox:
    """A one-slot hand-over from a subscriber callback to a worker: the newest item wins.

    ``put`` never blocks; an item replaced before it was taken is counted in ``dropped``.
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item = None
        self.received = 0
        self.dropped = 0

    def put(self, item) -> None:
        with self._cond:
            self.received += 1
            if self._item is not None:
                self.dropped += 1
            self._item = item
            self._cond.notify()

    def take(self, timeout: float):
        """The newest item (and empty the slot), or None after ``timeout`` s (wall clock)."""
        with self._cond:
            if self._item is None:
                self._cond.wait(timeout)
            item, self._item = self._item, None
            return item


class _Throttle:
    """Log a message at most once per ``period`` s (wall) per key, with the count since."""

    def __init__(self, period: float = 5.0):
        self.period = period
        self._last: Dict[str, float] = {}

    def due(self, key: str) -> bool:
        now = time.monotonic()
        if now - self._last.get(key, -math.inf) >= self.period:
            self._last[key] = now
            return True
        return False


class AbsOrientNode:
    """The node's state and its main loop; constructed after ``rospy.init_node``."""

    def __init__(self, config: NodeConfig, marker_map: MarkerMap):
        import rospy
        import tf2_ros
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PointStamped, PoseStamped, PoseWithCovarianceStamped
        from sensor_msgs.msg import CompressedImage, Image
        from visualization_msgs.msg import MarkerArray

        from ..msg import MarkerObservations
        from . import conversions as cv

        self.rospy, self.tf2_ros, self.cv = rospy, tf2_ros, cv
        self.config = config
        self.marker_map = marker_map
        self.pipeline: Optional[AbsOrientPipeline] = None
        self.time_offset = config.time_offset
        self.time_offset_source = "parameter"
        self.offset_estimator: Optional[OnlineOffsetEstimator] = None  # made with the pipeline (lever arm)
        self._selfcheck_lock = threading.Lock()   # fed by the image thread, read by the diagnostics timer
        self.selfcheck = self._new_selfcheck()
        self._selfcheck_report: Tuple[str, str, Dict[str, object]] = ("ok", "", {})
        self._selfcheck_wall = -math.inf
        self._state_saved_wall = -math.inf
        self._param_lock = threading.Lock()
        self._pending_params: Dict[str, object] = {}       # from dynamic_reconfigure (its thread)
        self._reconfigured: Dict[str, object] = {}          # the values it last handed over
        self._pending_for_pipeline: Dict[str, object] = {}  # waiting for the pipeline to exist
        self._throttle = _Throttle()

        self.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(30.0), debug=False)
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        self.tf_broadcaster = tf2_ros.TransformBroadcaster()
        self.pub_orientation = rospy.Publisher("abs_orient/orientation", PoseWithCovarianceStamped, queue_size=10)
        self.pub_prism_pose = rospy.Publisher("abs_orient/prism_pose", PoseWithCovarianceStamped, queue_size=10)
        self.pub_pose = rospy.Publisher("abs_orient/pose", PoseStamped, queue_size=10)
        self.pub_detections = rospy.Publisher("abs_orient/detections", MarkerObservations, queue_size=10)
        self.pub_markers = rospy.Publisher("abs_orient/markers", MarkerArray, queue_size=1, latch=True)
        self.pub_diagnostics = rospy.Publisher("/diagnostics", DiagnosticArray, queue_size=10)

        # counters and state (main thread only, except the mailbox and the prism deque)
        self.images = Mailbox()
        self.prisms: Deque[Tuple[float, np.ndarray]] = collections.deque(maxlen=1000)
        self.prism_errors: Deque[str] = collections.deque(maxlen=100)
        self.counts: Dict[str, int] = collections.Counter()
        self.last_error = ""
        self.latencies_ms: Deque[float] = collections.deque(maxlen=600)
        self.stage_ms: Dict[str, float] = {}  # ms per stage summed since the last diagnostics report
        self.last_image_stamp: Optional[float] = None     # s, camera clock
        self.last_prism_stamp: Optional[float] = None     # s, total-station clock
        self.last_image_wall = time.monotonic()
        self.last_tf_stamp: Optional[float] = None        # s, newest map→odom stamp sent
        self.sent_tf_stamps: Deque[float] = collections.deque(maxlen=64)
        self.initialised = False                          # the pipeline's filter, from the last good frame
        self.last_result: Optional[FrameResult] = None
        self.seen_ids: Tuple[int, ...] = ()
        self._diag_prev: Dict[str, int] = {}
        self._diag_wall = time.monotonic()

        if config.image_transport == "compressed":
            self.image_sub = rospy.Subscriber("camera/image/compressed", CompressedImage, self._on_image,
                                              queue_size=1, buff_size=1 << 26, tcp_nodelay=True)
            self._decode = cv.image_from_compressed
        else:
            self.image_sub = rospy.Subscriber("camera/image", Image, self._on_image, queue_size=1,
                                              buff_size=1 << 26, tcp_nodelay=True)
            self._decode = cv.image_from_raw
        self.prism_sub = rospy.Subscriber("ms60/prism", PointStamped, self._on_prism, queue_size=50)
        self.pub_markers.publish(cv.marker_array(marker_map, rospy.Time.now()))
        self._start_reconfigure()

    # ------------------------------------------------------------------ callbacks (rospy threads)
    def _on_image(self, msg) -> None:
        self.images.put((msg, time.monotonic()))

    def _on_prism(self, msg) -> None:
        try:
            t, p = self.cv.point_stamped_to_array(msg, self.config.map_frame)
        except self.cv.ConversionError as e:
            self.prism_errors.append(str(e))
            return
        self.prisms.append((t, p))

    def _start_reconfigure(self) -> None:
        try:
            from dynamic_reconfigure.server import Server

            from ..cfg import AbsOrientConfig
        except ImportError as e:
            self.rospy.logwarn(f"abs_orient: dynamic_reconfigure unavailable ({e}): parameters fixed at start-up")
            return
        self.reconfigure_server = Server(AbsOrientConfig, self._on_reconfigure)

    def _on_reconfigure(self, config, level):
        # the server hands over every parameter each time: pass on only what changed (a detection
        # parameter rebuilds the tracker, which then searches the full frame once)
        with self._param_lock:
            for k in reconfigurable_names():
                if k in config and self._reconfigured.get(k) != config[k]:
                    self._pending_params[k] = self._reconfigured[k] = config[k]
        return config

    # ------------------------------------------------------------------ main loop
    def run(self) -> None:
        """Process images until shutdown (the calling thread is the worker)."""
        period = 1.0 / self.config.tf_rate
        while not self.rospy.is_shutdown():
            item = self.images.take(timeout=period)
            self._apply_params()
            if item is not None:
                self._process(*item)
            self._republish_map_odom()
            if time.monotonic() - self._diag_wall >= 1.0 / self.config.diagnostics_rate:
                self._publish_diagnostics()

    def _apply_params(self) -> None:
        with self._param_lock:
            changes, self._pending_params = self._pending_params, {}
        if not changes:
            return
        if "time_offset" in changes:
            self.time_offset = float(changes.pop("time_offset"))
            self.time_offset_source = "parameter"
        self._pending_for_pipeline.update(changes)
        if self.pipeline is not None:
            self._update_pipeline_params()

    def _update_pipeline_params(self) -> None:
        changes, self._pending_for_pipeline = self._pending_for_pipeline, {}
        if not changes:
            return
        try:
            self.pipeline.update_params(**changes)
        except (PipelineError, ValueError, TypeError) as e:
            self._error("bad_params", f"parameters not applied: {e}")

    def _error(self, key: str, text: str) -> None:
        self.counts[key] += 1
        self.last_error = text
        if self._throttle.due(key):
            self.rospy.logwarn(f"abs_orient: {text} ({self.counts[key]} so far)")

    def _new_selfcheck(self) -> RollingSelfCheck:
        return RollingSelfCheck({m.id: m.position for m in self.marker_map}, time_offset=self.time_offset)

    def _feed_selfcheck(self, result: FrameResult, odom_T_base: np.ndarray) -> None:
        """The frame's marker yaws and pose for the rolling self-checks (time offset, tilt, moved marker)."""
        odom_yaw = float(yaw_of(odom_T_base[:3, :3]))
        with self._selfcheck_lock:
            for r in result.observations:
                if math.isfinite(r.yaw):
                    o = r.observation
                    self.selfcheck.add_observation(result.stamp, o.id, o.azimuth, o.elevation, r.yaw_sigma,
                                                   r.residual, r.accepted, r.yaw, odom_yaw)
            if result.map_T_base is not None:
                self.selfcheck.add_pose(result.stamp, float(yaw_of(result.map_T_base[:3, :3])))

    def _selfcheck_status(self, now_wall: float) -> Tuple[str, str, Dict[str, object]]:
        """The rolling self-checks, evaluated at most every 5 s (a fit over up to 120 s of observations)."""
        if now_wall - self._selfcheck_wall >= 5.0:
            self._selfcheck_wall = now_wall
            with self._selfcheck_lock:
                try:
                    self._selfcheck_report = self.selfcheck.diagnostics()
                except Exception as e:  # a check must never take the node down
                    self._selfcheck_report = ("ok", "", {"self-check note": f"{type(e).__name__}: {e}"})
        return self._selfcheck_report

    def _reset(self, why: str) -> None:
        self.rospy.logwarn(f"abs_orient: {why}: resetting (filter, tracking, prism history, tf buffer)")
        self.counts["resets"] += 1
        if self.pipeline is not None:
            self.pipeline.reset()
        self.tf_buffer.clear()  # static transforms survive a clear
        self.last_image_stamp = self.last_prism_stamp = self.last_tf_stamp = None
        self.sent_tf_stamps.clear()
        self.last_result = None
        self.initialised = False
        if self.offset_estimator is not None:
            self.offset_estimator.clear()
        with self._selfcheck_lock:
            self.selfcheck = self._new_selfcheck()

    def _ensure_pipeline(self) -> bool:
        if self.pipeline is not None:
            return True
        c = self.config
        calibrated = c.calibrated_lever_arms()
        source = f"calibration {c.calibration}" if calibrated else "tf"
        arms = {} if calibrated is None else {c.camera_frame: calibrated["camera"], c.prism_frame: calibrated["prism"]}
        for child in (c.camera_frame, c.prism_frame):
            if child in arms:
                continue
            try:
                tr = self.tf_buffer.lookup_transform(c.base_frame, child, self.rospy.Time(0))
                arms[child] = self.cv.transform_to_matrix(tr.transform, f"{c.base_frame}->{child}")
            except (self.tf2_ros.TransformException, self.cv.ConversionError) as e:
                self._error("no_static_tf", f"waiting for the static tf {c.base_frame} -> {child}: {e}")
                return False
        try:
            self.pipeline = AbsOrientPipeline(self.marker_map, arms[c.camera_frame], arms[c.prism_frame])
            if c.estimate_time_offset:  # the prism's lever arm turns its track heading in turns (timesync)
                self.offset_estimator = OnlineOffsetEstimator(prism_in_base=arms[c.prism_frame][:3, 3])
        except PipelineError as e:
            self._error("no_static_tf", f"unusable lever arms from {source}: {e}")
            return False
        self._update_pipeline_params()
        camera, prism = arms[c.camera_frame][:3, 3].round(3), arms[c.prism_frame][:3, 3].round(3)
        self.rospy.loginfo(f"abs_orient: lever arms from {source}: camera at {camera} m, prism at {prism} m "
                           f"in {c.base_frame}")
        self._restore_state()
        return True

    def _restore_state(self) -> None:
        """Start the filter from ``~state_file`` when it is recent (a respawn while the robot drives)."""
        c = self.config
        if not c.state_file or not os.path.exists(c.state_file):
            return
        now = self.rospy.get_time() - self.time_offset
        try:
            with open(c.state_file) as f:
                why = self.pipeline.filter.restore(json.load(f), now, c.state_max_age)
        except (OSError, ValueError) as e:
            why = f"cannot read it: {e}"
        if why:
            self.rospy.loginfo(f"abs_orient: not starting from {c.state_file}: {why}")
            return
        self.initialised = True
        self.rospy.loginfo(f"abs_orient: started from the map->odom state in {c.state_file} "
                           f"({self.pipeline.filter.stats.restored_age:.2f} s old)")

    def _save_state(self, now_wall: float) -> None:
        """Write the filter's state to ``~state_file`` (atomically, at most once a second)."""
        c = self.config
        if not c.state_file or now_wall - self._state_saved_wall < 1.0:
            return
        snap = self.pipeline.filter.snapshot() if self.pipeline is not None else None
        if snap is None:
            return
        self._state_saved_wall = now_wall
        try:
            atomic_write_text(c.state_file, json.dumps(snap) + "\n")
        except OSError as e:
            self._error("state_file", f"~state_file {c.state_file}: cannot write: {e}")

    def _feed_prisms(self) -> None:
        while self.prism_errors:
            self._error("bad_prism", f"ms60/prism: {self.prism_errors.popleft()}")
        while self.prisms and self.pipeline is not None:  # kept (bounded) until the pipeline exists
            t, p = self.prisms.popleft()
            if self.last_prism_stamp is not None and t < self.last_prism_stamp - self.config.time_jump_tolerance:
                self._reset(f"ms60/prism time jumped back by {self.last_prism_stamp - t:.3f} s")
            self.last_prism_stamp = t if self.last_prism_stamp is None else max(t, self.last_prism_stamp)
            self.counts["prisms"] += 1
            self.pipeline.add_prism(t, p)
            with self._selfcheck_lock:
                self.selfcheck.add_prism(t, p)
            if self.offset_estimator is not None:
                self.offset_estimator.add_track(t, float(p[0]), float(p[1]))

    def _odom_T_base(self, stamp) -> Optional[np.ndarray]:
        """odom→base_link at ``stamp``, waiting up to ~tf_timeout (wall clock) for it to arrive."""
        c = self.config
        deadline = time.monotonic() + c.tf_timeout
        while True:
            try:
                tr = self.tf_buffer.lookup_transform(c.odom_frame, c.base_frame, stamp)
                break
            except self.tf2_ros.ExtrapolationException as e:
                if time.monotonic() < deadline:
                    time.sleep(0.002)
                    continue
                self._error("tf_failures", f"tf {c.odom_frame} -> {c.base_frame} at the image time: {e}")
                return None
            except self.tf2_ros.TransformException as e:
                self._error("tf_failures", f"tf {c.odom_frame} -> {c.base_frame}: {e}")
                return None
        try:
            return self.cv.transform_to_matrix(tr.transform, f"tf {c.odom_frame}->{c.base_frame}")
        except self.cv.ConversionError as e:
            self._error("tf_nan", str(e))
            return None

    def _process(self, msg, received_wall: float) -> None:
        cv = self.cv
        stamp = msg.header.stamp
        s = cv.stamp_to_sec(stamp)
        self.last_image_wall = time.monotonic()
        if self.last_image_stamp is not None:
            if s < self.last_image_stamp - self.config.time_jump_tolerance:
                self._reset(f"image time jumped back by {self.last_image_stamp - s:.3f} s")
            elif s <= self.last_image_stamp:
                self._error("out_of_order",
                            f"image stamp {s:.3f} s not after the previous one, {self.last_image_stamp:.3f} s")
                return
        self.last_image_stamp = s
        self._feed_prisms()
        if not self._ensure_pipeline():
            return
        try:
            image = self._decode(msg)
        except cv.ConversionError as e:
            self._error("bad_images", str(e))
            return
        tf_wait = time.monotonic()
        odom_T_base = self._odom_T_base(stamp)
        if odom_T_base is None:
            return
        tf_wait_ms = 1e3 * (time.monotonic() - tf_wait)
        self._feed_prisms()  # what arrived while waiting for tf
        bad_before = self.pipeline.stats.get("bad_images", 0)
        try:
            result = self.pipeline.process_image(s - self.time_offset, image, odom_T_base)
        except Exception as e:  # the pipeline promises not to raise; a live robot must not stop if it does
            self._error("pipeline_exceptions", f"pipeline failed on the image at {s:.3f} s: {type(e).__name__}: {e}")
            if self.counts["pipeline_exceptions"] == 1:
                self.rospy.logerr("abs_orient: first pipeline failure, with traceback:\n" + traceback.format_exc())
            return
        self.counts["processed"] += 1
        if result.error:
            corrupt = self.pipeline.stats.get("bad_images", 0) > bad_before
            self._error("bad_images" if corrupt else "frame_errors", result.error)
        else:
            self.initialised = result.initialised
        unknown = result.tracking.rejected_unknown if result.tracking is not None else 0
        if unknown:
            self.counts["unknown_ids"] += unknown
        self._publish(result, stamp, odom_T_base)
        self.latencies_ms.append(1e3 * (time.monotonic() - received_wall))
        self._save_state(time.monotonic())
        self._feed_selfcheck(result, odom_T_base)
        self._estimate_time_offset(s, odom_T_base, result)
        for stage, ms in result.timings.items():
            self.stage_ms[stage] = self.stage_ms.get(stage, 0.0) + ms
        self.stage_ms["tf wait"] = self.stage_ms.get("tf wait", 0.0) + tf_wait_ms

    def _estimate_time_offset(self, s: float, odom_T_base: np.ndarray, result: FrameResult) -> None:
        """Feed the live estimator (camera clock ``s``); start an estimate when one is due; switch to a
        confident estimate that contradicts the offset in use."""
        est = self.offset_estimator
        if est is None:
            return
        est.add_vo(s, float(yaw_of(odom_T_base[:3, :3])))
        if result.fused_yaw is not None and any(r.accepted for r in result.observations):
            est.add_marker_yaw(s, result.fused_yaw)
        est.update_in_background(s)
        better = est.suggestion(self.time_offset) if self.config.apply_estimated_time_offset else None
        if better is not None:
            self.rospy.logwarn(f"abs_orient: time offset {self.time_offset:.4f} s -> {better:.4f} s "
                               f"(live estimate ± {1e3 * est.applied_sigma:.1f} ms contradicts the one in use)")
            self.time_offset, self.time_offset_source = better, "live estimate"

    # ------------------------------------------------------------------ outputs
    def _publish(self, result: FrameResult, stamp, odom_T_base: np.ndarray) -> None:
        cv, c = self.cv, self.config
        self.last_result = result
        self.pub_detections.publish(cv.observations_msg(result.observations, stamp, c.camera_frame))
        if result.map_T_odom is not None:
            self._send_map_odom(cv.stamp_to_sec(stamp), result.map_T_odom)
        if result.fused_yaw is not None and any(r.accepted for r in result.observations):
            # the frame's own marker yaw (not the filtered one, which already used the odometry)
            self.pub_orientation.publish(cv.orientation_msg(result.fused_yaw, result.fused_yaw_sigma, odom_T_base,
                                                            stamp, c.map_frame))
            self.counts["frames_with_yaw"] += 1
        prism_pose = cv.prism_pose_msg(result, stamp, c.map_frame)
        if prism_pose is not None:
            self.pub_prism_pose.publish(prism_pose)
        pose = cv.pose_msg(result, stamp, c.map_frame)
        if pose is not None:
            self.pub_pose.publish(pose)
        seen = tuple(sorted({r.id for r in result.observations if r.accepted}))
        if seen != self.seen_ids:
            self.seen_ids = seen
            self.pub_markers.publish(cv.marker_array(self.marker_map, stamp, seen))

    def _send_map_odom(self, stamp_sec: float, map_T_odom: np.ndarray) -> None:
        if stamp_sec in self.sent_tf_stamps:
            return  # tf2 drops a repeated stamp of an edge (TF_REPEATED_DATA) and complains
        self.sent_tf_stamps.append(stamp_sec)
        self.last_tf_stamp = stamp_sec if self.last_tf_stamp is None else max(stamp_sec, self.last_tf_stamp)
        if self.config.publish_tf:
            c = self.config
            self.tf_broadcaster.sendTransform(
                self.cv.matrix_to_transform_stamped(map_T_odom, self.cv.sec_to_stamp(stamp_sec), c.map_frame,
                                                    c.odom_frame))
            self.counts["tf_published"] += 1

    def _republish_map_odom(self) -> None:
        """map→odom at the newest odometry stamp when it is 1/tf_rate past the newest one sent (images
        stalled, dropped or slower than tf_rate): the filter's prediction there."""
        if self.pipeline is None or not self.initialised:
            return
        c = self.config
        try:
            latest = self.tf_buffer.get_latest_common_time(c.odom_frame, c.base_frame)
        except self.tf2_ros.TransformException:
            return
        s = self.cv.stamp_to_sec(latest)
        if self.last_tf_stamp is not None and s < self.last_tf_stamp + 1.0 / c.tf_rate:
            return
        map_T_odom, _ = self.pipeline.map_T_odom(s - self.time_offset)
        self._send_map_odom(s, map_T_odom)
        self.counts["tf_republished"] += 1

    def health(self, now_wall: float, now_ros: float) -> Tuple[str, str, Dict[str, object]]:
        """(level, message, values) of the node for /diagnostics; levels from what happened since the
        last report (so the status recovers as soon as the input is good again)."""
        c = self.config
        delta = {k: v - self._diag_prev.get(k, 0) for k, v in self.counts.items()}
        dt = max(now_wall - self._diag_wall, 1e-6)
        received = self.images.received
        dropped = self.images.dropped
        lat = np.array(self.latencies_ms) if self.latencies_ms else np.array([np.nan])
        prism_age = now_ros - self.last_prism_stamp if self.last_prism_stamp is not None else math.inf
        image_age = now_wall - self.last_image_wall
        r = self.last_result
        values: Dict[str, object] = {
            "initialised": self.initialised,
            "markers seen": len(self.seen_ids),
            "marker ids": " ".join(str(i) for i in self.seen_ids) or "-",
            "rate [Hz]": delta.get("processed", 0) / dt,
            "images received": received,
            "images processed": self.counts["processed"],
            "images dropped": dropped,
            "dropped fraction": dropped / received if received else 0.0,
            "latency median [ms]": float(np.median(lat)),
            "latency p95 [ms]": float(np.percentile(lat, 95)),
            "time offset [s]": self.time_offset,
            "time offset source": self.time_offset_source,
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
            "publish_tf": c.publish_tf,
            "map->odom sent": self.counts["tf_published"],
            "last error": self.last_error or "-",
        }
        est = self.offset_estimator
        if est is not None:
            latest = est.latest
            values["time offset estimate [s]"] = latest.offset if latest is not None else "-"
            values["time offset estimate sigma [ms]"] = 1e3 * latest.sigma if latest is not None else "-"
            values["time offset estimate confidence"] = latest.confidence if latest is not None else "-"
            values["time offset estimate note"] = est.last_error or "-"
        if r is not None and r.map_T_odom is not None:
            values["map->odom yaw [deg]"] = math.degrees(float(yaw_of(r.map_T_odom[:3, :3])))
        n = max(delta.get("processed", 0), 1)
        for stage, ms in self.stage_ms.items():
            values[f"stage {stage} [ms]"] = ms / n
        if self.pipeline is not None:
            for k, v in sorted(self.pipeline.stats.items()):
                values["pipeline " + k] = v
            fs = self.pipeline.filter.stats
            values["filter waiting reason"] = self.pipeline.waiting_reason or "-"
            values["filter lock-out recoveries"] = fs.lockout_recoveries
            values["filter re-initialisations"] = fs.reinitialisations
            values["filter yaw noise scale"] = fs.noise_scale
            values["filter restored from a state [s old]"] = fs.restored_age if math.isfinite(fs.restored_age) else "-"
        problems = []
        level = "ok"
        if self.pipeline is None and delta.get("no_static_tf", 0):
            level = "error"
            problems.append(f"no static tf {c.base_frame} -> {c.camera_frame}/{c.prism_frame}")
        if image_age > c.image_timeout:
            problems.append(f"no image for {image_age:.1f} s")
        if prism_age > c.prism_timeout:
            problems.append(("no prism yet" if not self.prisms else "prisms arrive, waiting for the first image")
                            if math.isinf(prism_age) else f"no prism for {prism_age:.1f} s")
        for key, text in (("bad_images", "corrupt images"), ("tf_failures", "tf lookups failed"),
                          ("tf_nan", "NaN in tf"), ("frame_errors", "frame errors"), ("unknown_ids", "unknown ids"),
                          ("bad_prism", "bad prism messages"), ("pipeline_exceptions", "pipeline failures"),
                          ("bad_params", "reconfigured parameters refused"),
                          ("resets", "time jumped back: reset"), ("state_file", "state file writes failed")):
            if delta.get(key, 0):
                problems.append(f"{delta[key]} {text}")
        if problems and level == "ok":
            level = "warn"
        if not problems and not self.initialised:
            level = "warn"
            why = self.pipeline.waiting_reason if self.pipeline is not None else "waiting for the static tfs"
            problems.append(f"initialising: {why}")
        message = "; ".join(problems) if problems else f"tracking {len(self.seen_ids)} marker(s)"
        return level, message, values

    def _publish_diagnostics(self) -> None:
        now_wall = time.monotonic()
        level, message, values = self.health(now_wall, self.cv.stamp_to_sec(self.rospy.Time.now()))
        status = self.cv.diagnostic_status("abs_orient: pipeline", level, message, values,
                                           hardware_id=self.rospy.get_name())
        check_level, check_message, check_values = self._selfcheck_status(now_wall)
        check = self.cv.diagnostic_status("abs_orient: self-check", check_level,
                                          check_message or "not enough observations yet", check_values,
                                          hardware_id=self.rospy.get_name())
        self.pub_diagnostics.publish(self.cv.diagnostic_array(self.rospy.Time.now(), [status, check]))
        self._diag_prev = dict(self.counts)
        self._diag_wall = now_wall
        self.stage_ms.clear()


def reconfigurable_names() -> Tuple[str, ...]:
    """Names cfg/AbsOrient.cfg may expose: the node's own plus every pipeline tunable."""
    return RECONFIGURABLE_NODE_PARAMS + tuple(name for _, name, _ in all_param_fields())


def main(argv=None) -> int:
    """Entry point of ``scripts/abs_orient``; returns the exit status (1: no ROS master, 2: bad
    parameters or marker map, each with one line)."""
    import rospy

    from . import exit_without_master

    exit_without_master("abs_orient", "live.launch", argv)
    rospy.init_node("abs_orient", argv=argv)
    try:
        config = NodeConfig.from_params(rospy.get_param)
        marker_map = MarkerMap.load(config.markers)
    except (NodeConfigError, MarkerMapError) as e:
        rospy.logfatal(f"abs_orient: {e}")
        return 2
    node = AbsOrientNode(config, marker_map)
    rospy.loginfo(f"abs_orient: {len(marker_map)} markers from {config.markers}; "
                  f"{'publishing' if config.publish_tf else 'NOT publishing (EKF owns it)'} "
                  f"{config.map_frame} -> {config.odom_frame}")
    node.run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
