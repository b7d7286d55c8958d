"""The ``abs_orient`` node: marker bearings in 360° images → tf ``map → odom`` and absolute inputs for
robot_localization (doc/design.md §3). A thin shell around :class:`aruco_abs_orient.pipeline.AbsOrientPipeline`.

Inputs: ``camera/image/compressed`` (``sensor_msgs/CompressedImage``) or, with ``~image_transport: raw``,
``camera/image`` (``sensor_msgs/Image``); ``ms60/prism`` (``geometry_msgs/PointStamped`` in map), or once
it is heard ``ms60/prism_with_covariance`` (``PoseWithCovarianceStamped``: the same positions, each with the
instrument's covariance, which the filter and ``abs_orient/prism_pose`` then use instead of ``prism_sigma``); tf
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
  arm removed; ``abs_orient/pose_markers`` (``PoseWithCovarianceStamped``): base_link's pose from a resection
  on the frame's markers (no prism: ``~markers_only``, or a prism dropout), covariance from the geometry;
  ``abs_orient/pose`` (``PoseStamped``): the corrected pose; ``abs_orient/odometry`` (``nav_msgs/Odometry``, while
  someone subscribes): base_link in map at every new odometry stamp, the odometry corrected by the filter's
  map→odom prediction (its drift rate between marker yaws), the yaw's variance the filter's, position and
  roll/pitch with step σs: robot_localization's heading and motion input (cfg/ekf.yaml); ``abs_orient/detections``;
  ``abs_orient/markers`` (rviz ``MarkerArray``, latched); ``abs_orient/rays`` (``MarkerArray``: a line
  from the camera to each accepted marker of the frame, in the camera frame); ``~debug_image``
  (``Image`` bgr8) and ``~debug_image/compressed`` (``CompressedImage``, JPEG: image_transport's compressed
  transport of it), each only while someone subscribes to it, at most ``~debug_rate`` Hz: the frame at
  ≤ ``~debug_width`` px with the detections, the predicted markers, the seam and the horizon drawn by
  :mod:`aruco_abs_orient.debugview`);
  ``/diagnostics`` through diagnostic_updater (hardware id: the camera frame): the ``pipeline`` status
  (:class:`aruco_abs_orient.nodestate.NodeHealth`), the ``self-check``, frequency statuses of images
  processed, prism positions and map→odom sent, timestamp statuses of the image age and the prism stamp offset.

Time. ``~time_offset`` (s): camera stamps = true (total-station) time + offset; the pipeline works in
total-station time (``stamp − offset``), the published messages keep the image stamp. ``map → odom``
estimated at an image's time ``t`` is stamped ``t + ~transform_tolerance`` (future-dated, as amcl), and
re-published with the filter's prediction at the newest ``odom → base_link`` stamp ``s`` (stamped
``s + ~transform_tolerance``) when that is ``1/~tf_rate`` s past the newest stamp sent; the stamps sent
only go forward (a frame too late for that corrects the filter and goes out at the next newer stamp).
The policy is :class:`aruco_abs_orient.nodestate.MapOdomStamps` (ROS-free, unit-tested). A stamp going
back by more than ``~time_jump_tolerance`` s (sim time: a bag looped or restarted) resets the pipeline
and clears the tf buffer.

Real time. The image callback only drops the message into a one-slot mailbox (the newest wins; a
replaced, unprocessed image is counted as dropped: the oldest goes, nothing queues); a decoder thread turns
the newest message into its grey frame (JPEG decoded: libjpeg releases the GIL) as soon as the main thread
has taken the previous frame, so decoding the next image overlaps processing this one; the main thread
processes the frames. Subscriber ``queue_size=1`` with a large ``buff_size``: no queue can grow. When images
are dropped, ``/diagnostics`` warns with the rate achieved. Stage times (ms per processed image) in
``/diagnostics``: decode, track, solve, publish. Prism messages go through a bounded deque.

Bad input never stops the node: a corrupt image, unknown ids, NaN/missing tf, no prism — each is counted,
logged (throttled) and reported on ``/diagnostics``, and processing carries on with the next message. A
configuration that cannot work (a marker map or calibration file that does not load, a bad parameter) →
one line (``[FATAL] ... abs_orient: <file>: <field>: <problem>``); started by roslaunch, the node then stays
up doing nothing but reporting that line as an ERROR on ``/diagnostics`` (``configuration error: …``), so that
``respawn`` does not restart it in a loop; started otherwise, it exits with status 2.

The map check (:mod:`aruco_abs_orient.mapcheck`, every 2 s, once it fits every 15 s, in a worker thread, over
the last 60 s of marker sightings and prism positions): a marker map that does not fit what the camera sees
(another site's, rotated, shifted, scaled, a wrong origin) is an ERROR on ``/diagnostics`` (the ``pipeline``
and ``map check`` statuses, naming how the map is off); from then on the node publishes no ``map → odom``, no
absolute yaw or pose and keeps no state.

``~state_file``: the node's name and the master's port are added to the file name, and the state records
the node, master and ``/run_id`` that wrote it: a state of another node or run is ignored with the reason.
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
from dataclasses import replace
from functools import cached_property
from typing import Deque, Dict, Optional, Tuple

import numpy as np

from ..debugview import DebugImageError, debug_frame, encode_debug_jpeg
from ..detection import DetectionError, frame_to_grey
from ..errors import AbsOrientError
from ..mapcheck import DOES_NOT_FIT, FITS, MapVerdict, RollingMapCheck
from ..markers import MarkerMap
from ..nodeconfig import NodeConfig, NodeConfigError
from ..nodestate import (
    IMAGE_JUMPED_BACK,
    IMAGE_NOT_AFTER,
    MapOdomPrediction,
    MapOdomStamps,
    NodeHealth,
    NodeSnapshot,
    live_offset_to_apply,
    state_path,
    state_record,
    state_snapshot,
)
from ..north import NorthReference
from ..pipeline import AbsOrientPipeline, FrameResult, PipelineError, all_param_fields
from ..selfcheck import ModelContext, RollingSelfCheck, YawObservation
from ..timesync import OnlineOffsetEstimator
from ..transforms import yaw_of
from ..tum import Trajectory, WriteError, atomic_write_text

__all__ = ["Mailbox", "AbsOrientNode", "main"]

#: node-level entries of cfg/AbsOrient.cfg (all others are pipeline tunables, see all_param_fields)
RECONFIGURABLE_NODE_PARAMS = ("time_offset",)


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
            self._cond.notify_all()

    def take(self, timeout: float):
        """The newest item (and empty the slot), or None after ``timeout`` s (wall clock)."""
        with self._cond:
            if self._item is None:
                self._cond.wait(timeout)
            item, self._item = self._item, None
            self._cond.notify_all()
            return item

    def wait_taken(self, timeout: float) -> bool:
        """Wait until the slot is empty (its item taken), at most ``timeout`` s (wall clock); True when empty."""
        with self._cond:
            return self._cond.wait_for(lambda: self._item is None, timeout)


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

    def __init__(self, config: NodeConfig, marker_map: MarkerMap, north: Optional[NorthReference] = None):
        import diagnostic_updater
        import rospy
        import tf2_ros
        from geometry_msgs.msg import PointStamped, PoseStamped, PoseWithCovarianceStamped
        from nav_msgs.msg import Odometry
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
        self.mapcheck: Optional[RollingMapCheck] = None  # made with the pipeline (lever arms)
        self.map_verdict = MapVerdict("undetermined", "the marker map is not checked yet", {})
        self.map_refused = ""      # the map check's message once the map does not fit: nothing map-based goes out
        self._mapcheck_worker: Optional[threading.Thread] = None
        self._mapcheck_wall = -math.inf
        self._state_saved_wall = -math.inf
        self._param_lock = threading.Lock()
        self._pending_params: Dict[str, object] = {}       # from dynamic_reconfigure (its thread)
        self._reconfigured: Dict[str, object] = {}          # the values it last handed over
        self._pending_for_pipeline: Dict[str, object] = {}  # waiting for the pipeline to exist
        self._throttle = _Throttle()
        self.stamps = MapOdomStamps(config.transform_tolerance, 1.0 / config.tf_rate, config.time_jump_tolerance)
        self._tf_lock = threading.Lock()  # the stamp policy and the prediction: image thread and tf timer
        self._prediction: Optional[MapOdomPrediction] = None  # of the filter, total-station time
        self.health = NodeHealth(config.image_timeout, config.prism_timeout, config.publish_tf, time.monotonic(),
                                 (config.base_frame, config.camera_frame, config.prism_frame))
        self.health.extra_values["tilt source"] = self._tilt_source
        self.north = north = north or NorthReference()  # the map and the prism positions are turned to it
        self.health.extra_values["north"] = north.describe
        self.health.extra_values["meridian convergence deg"] = lambda: math.degrees(north.gamma)
        self.health.extra_values["image topic"] = lambda: self.image_sub.resolved_name
        self.health.extra_values["marker map"] = lambda: self.map_verdict.status

        self.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(30.0), debug=False)
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        self.tf_broadcaster = tf2_ros.TransformBroadcaster()
        self.pub_orientation = rospy.Publisher("abs_orient/orientation", PoseWithCovarianceStamped, queue_size=10)
        self.pub_prism_pose = rospy.Publisher("abs_orient/prism_pose", PoseWithCovarianceStamped, queue_size=10)
        self.pub_pose = rospy.Publisher("abs_orient/pose", PoseStamped, queue_size=10)
        self.pub_detections = rospy.Publisher("abs_orient/detections", MarkerObservations, queue_size=10)
        self.pub_markers = rospy.Publisher("abs_orient/markers", MarkerArray, queue_size=1, latch=True)
        self.pub_rays = rospy.Publisher("abs_orient/rays", MarkerArray, queue_size=1)
        self.pub_debug = rospy.Publisher("~debug_image/compressed", CompressedImage, queue_size=1)
        self.pub_debug_raw = rospy.Publisher("~debug_image", Image, queue_size=1)
        self._debug_wall = -math.inf
        self._rays_shown = False
        self.pub_pose_markers = rospy.Publisher("abs_orient/pose_markers", PoseWithCovarianceStamped, queue_size=10)
        self.pub_odometry = rospy.Publisher("abs_orient/odometry", Odometry, queue_size=10)
        self._odometry_stamp = -math.inf  # of the last abs_orient/odometry (s, odometry clock)
        self.imu_tilts: Deque[Tuple[float, float, float, float]] = collections.deque(maxlen=1000)
        if config.imu_topic:
            from sensor_msgs.msg import Imu

            self.imu_sub = rospy.Subscriber(config.imu_topic, Imu, self._on_imu, queue_size=50)

        # counters and state (main thread only, except the mailbox and the prism deque)
        self.images = Mailbox()   # messages, from the subscriber callback
        self.frames = Mailbox()   # (message, receipt wall time, grey frame or why not, decode ms), decoder thread
        self.prisms: Deque[Tuple[float, np.ndarray, Optional[np.ndarray]]] = collections.deque(maxlen=1000)
        self.prism_covariances = 0  # positions that came with the instrument's covariance
        self.prism_errors: Deque[str] = collections.deque(maxlen=100)
        self.prism_stamps: Deque[float] = collections.deque(maxlen=1000)  # for the timestamp status
        self.last_prism_stamp: Optional[float] = None     # s, total-station clock
        self.last_image_wall = time.monotonic()
        self.initialised = False                          # the pipeline's filter, from the last good frame
        self.last_result: Optional[FrameResult] = None
        self._start_diagnostics(diagnostic_updater)

        if config.image_transport == "compressed":
            self.image_sub = rospy.Subscriber("camera/image/compressed", CompressedImage, self._on_image,
                                              queue_size=1, buff_size=1 << 26, tcp_nodelay=True)
            self._decode = cv.image_from_compressed
        else:
            self.image_sub = rospy.Subscriber("camera/image", Image, self._on_image, queue_size=1,
                                              buff_size=1 << 26, tcp_nodelay=True)
            self._decode = cv.image_from_raw
        self.prism_sub = rospy.Subscriber("ms60/prism", PointStamped, self._on_prism, queue_size=50)
        self.prism_cov_sub = rospy.Subscriber("ms60/prism_with_covariance", PoseWithCovarianceStamped,
                                              self._on_prism_with_covariance, queue_size=50)
        self.pub_markers.publish(cv.marker_array(marker_map, rospy.Time.now()))
        self._start_reconfigure()

    # ------------------------------------------------------------------ callbacks (rospy threads)
    def _on_image(self, msg) -> None:
        self.images.put((msg, time.monotonic()))

    def _on_prism(self, msg) -> None:
        if self.prism_covariances:  # the driver publishes each position with its covariance: taken from there
            return
        try:
            t, p = self.cv.point_stamped_to_array(msg, self.config.map_frame)
        except self.cv.ConversionError as e:
            self.prism_errors.append(str(e))
            return
        self._prism_in(t, p, None)

    def _on_prism_with_covariance(self, msg) -> None:
        try:
            t, p, cov = self.cv.prism_with_covariance(msg, self.config.map_frame)
        except self.cv.ConversionError as e:
            self.prism_errors.append(str(e))
            return
        self.prism_covariances += 1
        self._prism_in(t, p, cov)

    def _prism_in(self, t: float, p: np.ndarray, cov: Optional[np.ndarray]) -> None:
        p, cov = self.north.turn_point(p, cov)
        self.prisms.append((t, p, cov))
        self.diag_prisms.tick()
        self.diag_prism_offset.tick(t)

    def _start_diagnostics(self, du) -> None:
        """diagnostic_updater's tasks: the node's health, the self-check, three frequency statuses and two
        timestamp statuses (names in doc/ros_api.md); published every 1/~diagnostics_rate s."""
        c = self.config
        self.rospy.set_param("~diagnostic_period", 1.0 / c.diagnostics_rate)  # what the Updater reads
        self.updater = du.Updater()
        self.updater.setHardwareID(c.camera_frame)
        self.updater.add("pipeline", self._pipeline_task)
        self.updater.add("self-check", self._selfcheck_task)
        self.updater.add("map check", self._mapcheck_task)

        def frequency(name: str, low: float, high: float):
            return du.HeaderlessTopicDiagnostic(name, self.updater, du.FrequencyStatusParam(
                {"min": low, "max": high}, c.rate_tolerance, 10))

        self.diag_images = frequency("images processed", c.expected_image_rate, c.expected_image_rate)
        self.diag_prisms = frequency("prism positions", c.expected_prism_rate, c.expected_prism_rate)
        self.diag_tf = frequency("map->odom published", c.tf_rate, max(c.tf_rate, c.expected_image_rate))
        self.diag_image_age = du.TimeStampStatus(du.TimeStampStatusParam(-c.time_jump_tolerance, c.max_image_age),
                                                 "image age")
        self.diag_prism_offset = du.TimeStampStatus(du.TimeStampStatusParam(-c.time_jump_tolerance,
                                                                            c.prism_timeout), "prism stamp offset")
        self.updater.add(self.diag_image_age)
        self.updater.add(self.diag_prism_offset)

    def _on_imu(self, msg) -> None:
        """Roll and pitch of base_link from an IMU sample (its mounting rotation from tf), or counted as unusable."""
        from ..tilt import tilt_from_imu

        base = self.config.base_frame
        frame = msg.header.frame_id.lstrip("/") or base
        try:
            R = None if frame == base else self.cv.transform_to_matrix(
                self.tf_buffer.lookup_transform(base, frame, self.rospy.Time(0)).transform, f"{base}->{frame}")[:3, :3]
        except (self.tf2_ros.TransformException, self.cv.ConversionError):
            self.health.count("imu_unusable")
            return
        o, a, w = msg.orientation, msg.linear_acceleration, msg.angular_velocity
        tilt, _ = tilt_from_imu([o.x, o.y, o.z, o.w], msg.orientation_covariance, [a.x, a.y, a.z],
                                msg.linear_acceleration_covariance, [w.x, w.y, w.z], base_R_imu=R)
        if tilt is None:
            self.health.count("imu_unusable")
            return
        self.imu_tilts.append((self.cv.stamp_to_sec(msg.header.stamp),) + tuple(tilt))

    def _start_reconfigure(self) -> None:
        try:
            from dynamic_reconfigure.server import Server

            from ..cfg import AbsOrientConfig
        except ImportError as e:
            self.rospy.logwarn(f"abs_orient: dynamic_reconfigure unavailable ({e}): parameters fixed at start-up")
            return
        # the server starts from the ~section values, unless its ~name is set already: the node's own
        # (~markers_only), or what the server set before a respawn
        for name, value in self.config.tunables().flat().items():
            if name in AbsOrientConfig.defaults and not self.rospy.has_param("~" + name):
                self.rospy.set_param("~" + name, value)
        self.reconfigure_server = Server(AbsOrientConfig, self._on_reconfigure)

    def _on_reconfigure(self, config, level):
        # the server hands over every parameter each time: pass on only what changed (a detection or tracking
        # parameter rebuilds the tracker, which then searches the full frame once)
        with self._param_lock:
            for k in reconfigurable_names():
                if k in config and self._reconfigured.get(k) != config[k]:
                    self._pending_params[k] = self._reconfigured[k] = config[k]
        return config

    # ------------------------------------------------------------------ main loop
    def run(self) -> None:
        """Process images until shutdown (the calling thread is the worker; a second thread decodes)."""
        period = 1.0 / self.config.tf_rate
        timer = self.rospy.Timer(self.rospy.Duration(period / 2), self._republish_map_odom, reset=True)
        threading.Thread(target=self._decode_loop, name="decode", daemon=True).start()
        while not self.rospy.is_shutdown():
            item = self.frames.take(timeout=period)
            self._apply_params()
            if item is not None:
                self._process(*item)
            self._update_diagnostics()
        timer.shutdown()

    def _decode_loop(self) -> None:
        """The decoder thread: once the main thread has taken the previous frame, the newest message becomes
        its grey frame (a corrupt one: the reason, reported by the main thread). Images that arrive meanwhile
        replace each other in the message mailbox (the oldest is dropped, counted)."""
        while not self.rospy.is_shutdown():
            if not self.frames.wait_taken(timeout=0.1):
                continue
            item = self.images.take(timeout=0.1)
            if item is None:
                continue
            msg, received_wall = item
            start = time.perf_counter()
            pipeline = self.pipeline  # its params (jpeg_reduce) may change: read once per image
            reduce = (pipeline.params if pipeline is not None else self.config.tunables().pipeline).jpeg_reduce
            try:
                grey = frame_to_grey(self._decode(msg), int(reduce))
            except (self.cv.ConversionError, DetectionError) as e:
                grey = str(e)
            self.frames.put((msg, received_wall, grey, 1e3 * (time.perf_counter() - start)))

    def _update_diagnostics(self) -> None:
        """diagnostic_updater's periodic publication; after the clock jumped back (a looped bag) it would wait
        for the old timeline's next report time, and its frequency windows would span the jump: both restart."""
        if self.rospy.Time.now() < self.updater.last_time:
            self.updater.last_time = self.rospy.Time.now()
            for diag in (self.diag_images, self.diag_prisms, self.diag_tf):
                diag.clear_window()
        self.updater.update()

    def _apply_params(self) -> None:
        with self._param_lock:
            changes, self._pending_params = self._pending_params, {}
        if not changes:
            return
        if "time_offset" in changes:
            self._use_time_offset(float(changes.pop("time_offset")), "parameter")
        self._pending_for_pipeline.update(changes)
        if self.pipeline is not None:
            self._update_pipeline_params()

    def _update_pipeline_params(self) -> None:
        changes, self._pending_for_pipeline = self._pending_for_pipeline, {}
        if not changes:
            return
        try:
            self.pipeline.update_params(**changes)
        except (AbsOrientError, ValueError, TypeError) as e:
            self._error("bad_params", f"parameters not applied: {e}")

    def _error(self, key: str, text: str) -> None:
        n = self.health.error(key, text)
        if self._throttle.due(key):
            self.rospy.logwarn(f"abs_orient: {text} ({n} so far)")

    def _new_selfcheck(self) -> RollingSelfCheck:
        """The rolling self-checks; with the pipeline made, calibrate's model on the window (its mounting, lenses
        and readout)."""
        pipe, lever, model = self.pipeline, None, None
        if pipe is not None:
            lever = pipe.base_T_prism[:3, 3]
            none = Trajectory(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 4)))     # the window's, at each check
            model = ModelContext(self.marker_map, none, pipe.base_T_camera, pipe.base_T_prism, pipe.lenses,
                                 pipe.readout, self.config.tunables().calibration)
        p = self.config.tunables().selfcheck
        return RollingSelfCheck({m.id: m.position for m in self.marker_map}, time_offset=self.time_offset,
                                prism_lever=lever, model=model,
                                params=replace(p, model_observations=p.live_model_observations))

    def _feed_selfcheck(self, result: FrameResult, odom_T_base: np.ndarray) -> None:
        """The frame's marker yaws and pose for the rolling self-checks (time offset, tilt, moved marker)."""
        odom_yaw = float(yaw_of(odom_T_base[:3, :3]))
        if self.mapcheck is not None:
            for r in result.observations:
                self.mapcheck.add_sighting(result.stamp, r.id, r.observation.centre, odom_T_base[:3, :3])
        with self._selfcheck_lock:
            for r in result.observations:
                if math.isfinite(r.yaw):
                    o = r.observation
                    self.selfcheck.add_observation(YawObservation(result.stamp, o.id, o.azimuth, o.elevation,
                                                                  r.yaw_sigma, r.residual, r.accepted, r.yaw, odom_yaw,
                                                                  o.sigma))
            self.selfcheck.add_odometry(result.stamp, odom_T_base)
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
        self.health.count("resets")
        if self.pipeline is not None:
            self.pipeline.reset()
        self.tf_buffer.clear()  # static transforms survive a clear
        self.last_prism_stamp = None
        with self._tf_lock:
            self.stamps.reset()
            self._prediction = None
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
            readout = 0.0 if calibrated is None else float(calibrated.get("readout", 0.0))  # rolling shutter, s
            kwargs = c.tunables().pipeline_kwargs()
            if c.markers_only:
                kwargs["params"] = replace(kwargs["params"], markers_only=True)
            self.pipeline = AbsOrientPipeline(self.marker_map, arms[c.camera_frame], arms[c.prism_frame],
                                              readout=readout, calibrated=calibrated is not None, **kwargs,
                                              lenses=None if calibrated is None else calibrated.get("lenses"),
                                              lens_yaw_sigma=None if calibrated is None
                                              else calibrated.get("lens_yaw_sigma"))
            with self._selfcheck_lock:  # empty until now: started again with the pipeline's prism lever arm
                self.selfcheck = self._new_selfcheck()
            if not c.markers_only:
                self.mapcheck = RollingMapCheck({m.id: m.position for m in self.marker_map},
                                                self.pipeline.base_T_camera, self.pipeline.base_T_prism[:3, 3],
                                                self.marker_map.origin, params=replace(
                                                    c.tunables().mapcheck,
                                                    max_sightings=c.tunables().mapcheck.live_max_sightings))
            if c.estimate_time_offset:  # the prism's lever arm turns its track heading in turns (timesync)
                self.offset_estimator = OnlineOffsetEstimator(prism_in_base=arms[c.prism_frame][:3, 3],
                                                              params=c.tunables().timesync)
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
        if not c.state_file or not os.path.exists(self.state_file):
            return
        now = self.rospy.get_time() - self.time_offset
        try:
            with open(self.state_file) as f:
                snap, why = state_snapshot(json.load(f), self._state_writer)
            why = why or self.pipeline.filter.restore(snap, now, c.state_max_age)
        except (OSError, ValueError) as e:
            why = f"cannot read it: {e}"
        if why:
            self.rospy.loginfo(f"abs_orient: not starting from {self.state_file}: {why}")
            return
        self.initialised = True
        prediction = self._prediction_from(now)  # the state predicted to now: map->odom goes out at once
        with self._tf_lock:
            self._prediction = prediction
        self.rospy.loginfo(f"abs_orient: started from the map->odom state in {self.state_file} "
                           f"({self.pipeline.filter.stats.restored_age:.2f} s old)")

    def _save_state(self, now_wall: float) -> None:
        """Write the filter's state to ``~state_file`` (atomically, at most once a second)."""
        c = self.config
        if not c.state_file or now_wall - self._state_saved_wall < 1.0 or self.map_refused:
            return
        snap = self.pipeline.filter.snapshot() if self.pipeline is not None else None
        if snap is None:
            return
        self._state_saved_wall = now_wall
        try:
            atomic_write_text(self.state_file, json.dumps(state_record(snap, self._state_writer)) + "\n")
        except WriteError as e:
            self._error("state_file", f"~state_file {self.state_file}: cannot write: {e}")

    @cached_property
    def _state_writer(self) -> Dict[str, str]:
        """Who writes the state: this node's name, its master and the master's /run_id (a new roscore, a new id)."""
        return {"node": self.rospy.get_name(), "master": self._master_uri,
                "run_id": str(self.rospy.get_param("/run_id", ""))}

    @cached_property
    def _master_uri(self) -> str:
        import rosgraph

        return rosgraph.get_master_uri()

    @cached_property
    def state_file(self) -> str:
        """``~state_file`` with the node's name and the master's port in its name (nodes of different masters never
        share one)."""
        return state_path(self.config.state_file, self.rospy.get_name(), self._master_uri)

    def _check_map(self, now_wall: float) -> None:
        """Start the map check in a worker thread every 2 s (wall) until the map fits, then every 15 s (0.1-0.2 s of
        CPU each on 1000 sightings); take its verdict. A map that does not fit stops everything that depends on it,
        for good; later checks only say better how it is off (once its markers were seen from different places)."""
        worker = self._mapcheck_worker
        if self.mapcheck is None or (worker is not None and worker.is_alive()):
            return
        if now_wall - self._mapcheck_wall < (15.0 if self.map_verdict.status == FITS and not self.map_refused
                                             else 2.0):
            return
        self._mapcheck_wall = now_wall

        def check():
            try:
                verdict = self.mapcheck.check()
            except Exception as e:  # a check must never take the node down
                verdict = MapVerdict("undetermined", f"the map check failed: {type(e).__name__}: {e}", {})
            if self.map_refused and verdict.status != DOES_NOT_FIT:
                return  # refused for good: a later window of sightings does not take it back
            self.map_verdict = verdict
            if verdict.status == DOES_NOT_FIT:
                first = not self.map_refused
                self.map_refused = verdict.message
                with self._tf_lock:
                    self._prediction = None  # the timer stops re-publishing map->odom
                if first:
                    self.rospy.logerr(f"abs_orient: {verdict.message}: map->odom, the absolute yaw and pose are no "
                                      f"longer published (check ~markers {self.config.markers})")

        self._mapcheck_worker = threading.Thread(target=check, name="map check", daemon=True)
        self._mapcheck_worker.start()

    def _feed_prisms(self) -> None:
        while self.prism_errors:
            self._error("bad_prism", f"ms60/prism: {self.prism_errors.popleft()}")
        while self.prisms and self.pipeline is not None:  # kept (bounded) until the pipeline exists
            t, p, cov = self.prisms.popleft()
            if self.stamps.jumped_back(self.last_prism_stamp, t):
                self._reset(f"ms60/prism time jumped back by {self.last_prism_stamp - t:.3f} s")
            self.last_prism_stamp = t if self.last_prism_stamp is None else max(t, self.last_prism_stamp)
            self.health.count("prisms")
            self.pipeline.add_prism(t, p, cov)
            if self.mapcheck is not None:
                self.mapcheck.add_prism(t, p)
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

    def _process(self, msg, received_wall: float, image, decode_ms: float) -> None:
        """One decoded image (``image``: the grey frame, or why the message gave none)."""
        cv = self.cv
        stamp = msg.header.stamp
        s = cv.stamp_to_sec(stamp)
        self.last_image_wall = time.monotonic()
        with self._tf_lock:
            previous = self.stamps.last_image
            verdict = self.stamps.check_image(s)
        if verdict == IMAGE_JUMPED_BACK:
            self._reset(f"image time jumped back by {previous - s:.3f} s")
            with self._tf_lock:
                self.stamps.check_image(s)
        elif verdict == IMAGE_NOT_AFTER:
            self._error("out_of_order", f"image stamp {s:.3f} s not after the previous one, {previous:.3f} s")
            return
        self.diag_image_age.tick(s)
        self._feed_prisms()
        if not self._ensure_pipeline():
            return
        if isinstance(image, str):
            self._error("bad_images", image)
            return
        tf_wait = time.monotonic()
        odom_T_base = self._odom_T_base(stamp)
        if odom_T_base is None:
            return
        tf_wait_ms = 1e3 * (time.monotonic() - tf_wait)
        self._feed_prisms()  # what arrived while waiting for tf
        while self.imu_tilts:  # IMU stamps are on the robot's (camera/VO) clock
            t_imu, roll, pitch, sigma = self.imu_tilts.popleft()
            self.pipeline.add_imu(t_imu - self.time_offset, roll, pitch, sigma)
        bad_before = self.pipeline.stats.get("bad_images", 0)
        try:
            result = self.pipeline.process_image(s - self.time_offset, image, odom_T_base)
        except Exception as e:  # the pipeline promises not to raise; a live robot must not stop if it does
            self._error("pipeline_exceptions", f"pipeline failed on the image at {s:.3f} s: {type(e).__name__}: {e}")
            if self.health.counts["pipeline_exceptions"] == 1:
                self.rospy.logerr("abs_orient: first pipeline failure, with traceback:\n" + traceback.format_exc())
            return
        self.health.count("processed")
        self.diag_images.tick()
        if result.error:
            corrupt = self.pipeline.stats.get("bad_images", 0) > bad_before
            self._error("bad_images" if corrupt else "frame_errors", result.error)
        else:
            self.initialised = result.initialised
        unknown = result.tracking.rejected_unknown if result.tracking is not None else 0
        if unknown:
            self.health.count("unknown_ids", unknown)
        publish_start = time.perf_counter()
        self._publish(result, stamp, odom_T_base)
        self.health.latencies_ms.append(1e3 * (time.monotonic() - received_wall))
        publish_ms = 1e3 * (time.perf_counter() - publish_start)
        debug_start = time.perf_counter()
        self._publish_debug(msg, image, result)
        self.health.add_stages({"debug image": 1e3 * (time.perf_counter() - debug_start)})
        self._save_state(time.monotonic())
        self._feed_selfcheck(result, odom_T_base)
        self._check_map(time.monotonic())
        self._estimate_time_offset(s, odom_T_base, result)
        self.health.add_stages(result.timings)  # its decode: checking the decoded frame
        self.health.add_stages({"decode": decode_ms, "publish": publish_ms, "tf wait": tf_wait_ms})

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
        if not self.config.apply_estimated_time_offset:
            return
        with self._selfcheck_lock:
            better, vetoed = live_offset_to_apply(self.time_offset, est, self.selfcheck)
        if vetoed:
            self.health.count("time_offset_switch_refused")
            self.rospy.logwarn_throttle(30.0, f"abs_orient: keeping the time offset {self.time_offset:.4f} s: the "
                                              f"live estimate {est.applied:.4f} s contradicts it, but the marker yaws "
                                              "support it and contradict the estimate (self-check)")
        if better is not None:
            self.rospy.logwarn(f"abs_orient: time offset {self.time_offset:.4f} s -> {better:.4f} s "
                               f"(live estimate ± {1e3 * est.applied_sigma:.1f} ms contradicts the one in use)")
            self._use_time_offset(better, "live estimate")

    def _use_time_offset(self, offset: float, source: str) -> None:
        """Switch to the time offset ``offset`` (s) from ``source``; the self-checks start afresh on it (their
        marker yaws so far were made with the old one, and they measure the error of the offset in use)."""
        self.time_offset, self.time_offset_source = offset, source
        with self._selfcheck_lock:
            self.selfcheck = self._new_selfcheck()

    # ------------------------------------------------------------------ outputs
    def _publish(self, result: FrameResult, stamp, odom_T_base: np.ndarray) -> None:
        cv, c = self.cv, self.config
        self.last_result = result
        self.pub_detections.publish(cv.observations_msg(result.observations, stamp, c.camera_frame))
        if self.map_refused:  # nothing that depends on the marker map: only the detections (and the prism's pose)
            prism_pose = cv.prism_pose_msg(result, stamp, c.map_frame)
            if prism_pose is not None:
                self.pub_prism_pose.publish(prism_pose)
            return
        if result.map_T_odom is not None:
            prediction = self._prediction_from(result.stamp)
            with self._tf_lock:
                self._prediction = prediction
                self._send_map_odom(self.stamps.for_estimate(cv.stamp_to_sec(stamp)), result.map_T_odom)
        if result.fused_yaw is not None and any(r.accepted for r in result.observations):
            # the frame's own marker yaw (not the filtered one, which already used the odometry)
            self.pub_orientation.publish(cv.orientation_msg(result.fused_yaw, result.fused_yaw_sigma, odom_T_base,
                                                            stamp, c.map_frame))
            self.health.count("frames_with_yaw")
        prism_pose = cv.prism_pose_msg(result, stamp, c.map_frame)
        if prism_pose is not None:
            self.pub_prism_pose.publish(prism_pose)
        pose = cv.pose_msg(result, stamp, c.map_frame)
        if pose is not None:
            self.pub_pose.publish(pose)
        if result.marker_pose is not None and result.marker_pose_accepted:  # the frame's own resection
            self.pub_pose_markers.publish(cv.pose_with_covariance_msg(result.marker_pose, result.marker_pose_cov,
                                                                      stamp, c.map_frame))
        if result.observations or self._rays_shown:
            self.pub_rays.publish(cv.rays_marker_array(result.observations, stamp, c.camera_frame))
            self._rays_shown = bool(result.observations)
        if self.health.set_seen(r.id for r in result.observations if r.accepted):
            self.pub_markers.publish(cv.marker_array(self.marker_map, stamp, self.health.seen_ids))

    def _publish_debug(self, msg, image, result: FrameResult) -> None:
        """``~debug_image`` (raw, compressed) of this frame when someone subscribes to either and
        ``1/~debug_rate`` s (wall) passed since the last one."""
        c = self.config
        now = time.monotonic()
        jpeg_wanted, raw_wanted = self.pub_debug.get_num_connections(), self.pub_debug_raw.get_num_connections()
        if not (jpeg_wanted or raw_wanted) or now - self._debug_wall < 1.0 / c.debug_rate:
            return
        self._debug_wall = now
        try:
            map_T_camera = (result.map_T_base @ self.pipeline.base_T_camera if result.map_T_base is not None
                            else None)
            frame = debug_frame(image, result.observations, self.marker_map, map_T_camera, int(c.debug_width))
            jpeg = encode_debug_jpeg(frame) if jpeg_wanted else b""
        except (DebugImageError, ValueError) as e:
            self._error("debug_image", f"~debug_image: {e}")
            return
        if jpeg_wanted:
            self.pub_debug.publish(self.cv.compressed_image(jpeg, msg.header.stamp, c.camera_frame))
        if raw_wanted:
            self.pub_debug_raw.publish(self.cv.bgr_image(frame, msg.header.stamp, c.camera_frame))

    def _prediction_from(self, t: float) -> MapOdomPrediction:
        """The filter's prediction from time ``t`` (s, total-station time) on, for the tf timer."""
        (A, PA), (B, PB) = self.pipeline.map_T_odom(t), self.pipeline.map_T_odom(t + 1.0)
        return MapOdomPrediction(t, A, t + 1.0, B, (PA[0, 0], PB[0, 0]))

    def _send_map_odom(self, stamp_sec: Optional[float], map_T_odom: np.ndarray) -> None:
        """Broadcast ``map_T_odom`` at ``stamp_sec`` (s, already future-dated; None: held back by the stamp
        policy, counted). Called with ``_tf_lock`` held."""
        if stamp_sec is None:
            self.health.count("tf_held_back")
            return
        if self.config.publish_tf and not self.map_refused:
            c = self.config
            self.tf_broadcaster.sendTransform(
                self.cv.matrix_to_transform_stamped(map_T_odom, self.cv.sec_to_stamp(stamp_sec), c.map_frame,
                                                    c.odom_frame))
            self.health.count("tf_published")
            self.diag_tf.tick()

    def _republish_map_odom(self, _event=None) -> None:
        """rospy.Timer at 2·~tf_rate (its own thread, so an image being processed never delays it): the filter's
        prediction at the newest odometry stamp, when the stamp policy says one is due (images stalled,
        dropped, late or slower than tf_rate)."""
        c = self.config
        try:
            latest = self.tf_buffer.get_latest_common_time(c.odom_frame, c.base_frame)
        except self.tf2_ros.TransformException:
            return
        s = self.cv.stamp_to_sec(latest)
        with self._tf_lock:
            if self._prediction is None:  # not initialised (or just reset)
                return
            prediction, offset = self._prediction, self.time_offset
            stamp = self.stamps.republish(s)
            if stamp is not None:
                self._send_map_odom(stamp, prediction.at(s - offset))
                self.health.count("tf_republished")
        if s > self._odometry_stamp and self.pub_odometry.get_num_connections():
            self._odometry_stamp = s
            self._publish_odometry(latest, prediction, offset)

    def _publish_odometry(self, latest, prediction: MapOdomPrediction, offset: float) -> None:
        """``abs_orient/odometry``: base_link in map at the odometry's newest stamp, the odometry's pose corrected by
        the filter's map→odom prediction (its drift rate between marker yaws), with the yaw's variance."""
        c = self.config
        try:
            tr = self.tf_buffer.lookup_transform(c.odom_frame, c.base_frame, latest)
            odom_T_base = self.cv.transform_to_matrix(tr.transform, f"tf {c.odom_frame}->{c.base_frame}")
        except (self.tf2_ros.TransformException, self.cv.ConversionError):
            return
        t = self.cv.stamp_to_sec(latest) - offset
        self.pub_odometry.publish(self.cv.corrected_odometry_msg(prediction.at(t) @ odom_T_base,
                                                                 prediction.yaw_variance(t), latest, c.map_frame,
                                                                 c.base_frame))

    def _tilt_source(self) -> str:
        """Where the newest frame's roll and pitch came from (imu, markers, odometry), with unusable IMU samples."""
        r, unusable = self.last_result, self.health.counts["imu_unusable"]
        return ((r.tilt_source if r is not None and r.tilt_source else "-")
                + (f" ({unusable} IMU samples unusable)" if unusable else ""))

    def _pipeline_task(self, stat):
        """diagnostic_updater task ``pipeline``: :meth:`NodeHealth.report` since the previous update."""
        r = self.last_result
        level, message, values = self.health.report(time.monotonic(), self.rospy.get_time(), NodeSnapshot(
            initialised=self.initialised, image_age_wall=time.monotonic() - self.last_image_wall,
            last_prism_stamp=self.last_prism_stamp, prisms_waiting=bool(self.prisms),
            images_received=self.images.received, images_dropped=self.images.dropped + self.frames.dropped,
            time_offset=self.time_offset,
            time_offset_source=self.time_offset_source, pipeline=self.pipeline, offset_estimator=self.offset_estimator,
            map_odom_yaw=float(yaw_of(r.map_T_odom[:3, :3])) if r is not None and r.map_T_odom is not None else None))
        if self.map_refused:
            level, message = "error", f"{self.map_refused}; map->odom not published"
        return self.cv.fill_diagnostic(stat, level, message, values)

    def _mapcheck_task(self, stat):
        """diagnostic_updater task ``map check``: does the marker map fit what the camera sees (error when not)."""
        v = self.map_verdict
        values = {k: (json.dumps(x) if isinstance(x, (dict, list)) else x) for k, x in v.details.items()}
        return self.cv.fill_diagnostic(stat, "error" if v.status == DOES_NOT_FIT else "ok", v.message, values)

    def _selfcheck_task(self, stat):
        """diagnostic_updater task ``self-check``: the rolling self-checks (time offset, tilt, moved marker)."""
        level, message, values = self._selfcheck_status(time.monotonic())
        return self.cv.fill_diagnostic(stat, level, message or "not enough observations yet", values)


def reconfigurable_names() -> Tuple[str, ...]:
    """Names cfg/AbsOrient.cfg may expose: the node's own plus every pipeline tunable."""
    return RECONFIGURABLE_NODE_PARAMS + tuple(name for _, name, _ in all_param_fields())


def configuration_error(rospy, message: str, argv) -> int:
    """The node cannot run with its configuration: one FATAL line. Started by roslaunch (``__log:=`` among its
    arguments), it stays up reporting ``configuration error: <message>`` as an ERROR on ``/diagnostics`` until it
    is shut down, so that ``respawn`` does not start it again and again; otherwise it returns 2 at once."""
    rospy.logfatal(f"abs_orient: {message}")
    if not any(a.startswith("__log:=") for a in (sys.argv if argv is None else argv)):
        return 2
    import diagnostic_updater

    from . import conversions as cv

    updater = diagnostic_updater.Updater()
    updater.setHardwareID("abs_orient")
    text = (f"configuration error: {message}; the node does nothing until it is started again with a configuration "
            "that works (not respawned)")
    updater.add("pipeline", lambda stat: cv.fill_diagnostic(stat, "error", text, {"configuration error": message}))
    while not rospy.is_shutdown():
        updater.force_update()
        time.sleep(1.0)  # wall clock: a replay's sim clock may not run
    return 2


def main(argv=None) -> int:
    """Entry point of ``scripts/abs_orient``; returns the exit status (1: no ROS master, 2: bad
    parameters or marker map, each with one line; see :func:`configuration_error`)."""
    import rospy

    from . import exit_without_master, run_node

    exit_without_master("abs_orient", "live.launch", argv)
    rospy.init_node("abs_orient", argv=argv)
    return run_node("abs_orient", lambda: _run(rospy),
                    report=lambda message, _status: configuration_error(rospy, message, argv))


def _run(rospy) -> int:
    """Read the configuration and the marker map (an error of either: one line, see :func:`configuration_error`)
    and process images until shutdown."""
    config = NodeConfig.from_params(rospy.get_param)
    marker_map = MarkerMap.load(config.markers)
    north = NorthReference.make(config.north, marker_map.grid, marker_map.origin, "~")
    if config.markers_only and len(marker_map) < 3:
        raise NodeConfigError(f"{config.markers}: ~markers_only needs at least 3 markers in the map for a resection, "
                              f"it has {len(marker_map)}")
    node = AbsOrientNode(config, north.turn_map(marker_map), north)
    rospy.loginfo(f"abs_orient: headings referred to {north.describe()}")
    rospy.loginfo(f"abs_orient: {len(marker_map)} markers from {config.markers}; "
                  f"{'publishing' if config.publish_tf else 'NOT publishing (EKF owns it)'} "
                  f"{config.map_frame} -> {config.odom_frame}")
    node.run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
