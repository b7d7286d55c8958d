"""The ``abs_orient`` node: marker bearings in 360° images → tf ``map → odom`` and absolute inputs for
robot_localization (doc/design.md §3; topics, parameters, diagnostics and timing: doc/ros_api.md).

In: ``camera/image/compressed`` (or ``camera/image``), ``ms60/prism`` / ``ms60/prism_with_covariance``, tf
``odom → base_link`` and the static lever arms, ``~imu_topic``, dynamic_reconfigure, the marker map ``~markers``.
Out: tf ``map → odom``, ``abs_orient/*``, ``~debug_image``, ``/diagnostics``. This module is the ROS plumbing
only: subscribers, publishers, tf, diagnostic_updater, the decoder thread and the tf timer; every decision
(what a frame's result does, the stamp policy, resets, the time offset, the checks, the state file, what the
diagnostics say) is :class:`aruco_abs_orient.nodecontrol.NodeControl`'s, which it calls with converted messages
(``ros/conversions.py``). Bad input never stops the node; a configuration that cannot work is one FATAL line
(:func:`configuration_error`).
"""

from __future__ import annotations

import math
import sys
import threading
import time
from typing import Optional

import numpy as np

from ..debugview import DebugImageError, debug_frame, encode_debug_jpeg
from ..detection import DetectionError, frame_to_grey
from ..markers import MarkerMap
from ..nodeconfig import NodeConfig, NodeConfigError
from ..nodecontrol import RECONFIGURABLE_NODE_PARAMS, NodeControl, has_marker_yaw, reconfigurable_names
from ..north import NorthReference
from ..pipeline import FrameResult

__all__ = ["Mailbox", "AbsOrientNode", "main", "reconfigurable_names", "RECONFIGURABLE_NODE_PARAMS"]


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


class AbsOrientNode:
    """The node's ROS side and its main loop (its state and decisions: ``self.control``); constructed after
    ``rospy.init_node``."""

    def __init__(self, config: NodeConfig, marker_map: MarkerMap, north: Optional[NorthReference] = None):
        import diagnostic_updater
        import rosgraph
        import rospy
        import tf2_ros
        from geometry_msgs.msg import PointStamped, PoseWithCovarianceStamped
        from sensor_msgs.msg import CompressedImage, Image

        from . import conversions as cv

        self.rospy, self.tf2_ros, self.cv = rospy, tf2_ros, cv
        self.config = config
        self.marker_map = marker_map
        self.north = north = north or NorthReference()  # the map and the prism positions are turned to it
        self.control = ctl = NodeControl(
            config, marker_map, north, rospy, rospy.get_time,
            lambda: {"node": rospy.get_name(), "master": rosgraph.get_master_uri(),
                     "run_id": str(rospy.get_param("/run_id", ""))},
            on_reset=lambda: self.tf_buffer.clear())  # static transforms survive a clear
        self.health = ctl.health
        self.health.extra_values["tilt source"] = ctl.tilt_source
        self.health.extra_values["north"] = north.describe
        self.health.extra_values["meridian convergence deg"] = lambda: math.degrees(north.gamma)
        self.health.extra_values["image topic"] = lambda: self.image_sub.resolved_name
        self.health.extra_values["marker map"] = lambda: ctl.map_verdict.status

        self.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(30.0), debug=False)
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        self.tf_broadcaster = tf2_ros.TransformBroadcaster()
        self._start_publishers()
        if config.imu_topic:
            from sensor_msgs.msg import Imu

            self.imu_sub = rospy.Subscriber(config.imu_topic, Imu, self._on_imu, queue_size=50)
        self.images = Mailbox()   # messages, from the subscriber callback
        self.frames = Mailbox()   # (message, receipt wall time, grey frame or why not, decode ms), decoder thread
        self.prism_covariances = 0  # positions that came with the instrument's covariance
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

    def _start_publishers(self) -> None:
        """The node's topics (doc/ros_api.md)."""
        from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import CompressedImage, Image
        from visualization_msgs.msg import MarkerArray

        from ..msg import MarkerObservations

        rospy = self.rospy
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

    # ------------------------------------------------------------------ callbacks (rospy threads)
    def _on_image(self, msg) -> None:
        self.images.put((msg, time.monotonic()))

    def _on_prism(self, msg) -> None:
        if self.prism_covariances:  # the driver publishes each position with its covariance: taken from there
            return
        try:
            t, p = self.cv.point_stamped_to_array(msg, self.config.map_frame)
        except self.cv.ConversionError as e:
            self.control.prism_errors.append(str(e))
            return
        self._prism_in(t, p, None)

    def _on_prism_with_covariance(self, msg) -> None:
        try:
            t, p, cov = self.cv.prism_with_covariance(msg, self.config.map_frame)
        except self.cv.ConversionError as e:
            self.control.prism_errors.append(str(e))
            return
        self.prism_covariances += 1
        self._prism_in(t, p, cov)

    def _prism_in(self, t: float, p: np.ndarray, cov: Optional[np.ndarray]) -> None:
        self.control.prism_in(t, p, cov)
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
        self.control.imu_tilts.append((self.cv.stamp_to_sec(msg.header.stamp),) + tuple(tilt))

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
        self.control.reconfigured(config)
        return config

    # ------------------------------------------------------------------ main loop
    def run(self) -> None:
        """Process images until shutdown (the calling thread is the worker; a second thread decodes)."""
        period = 1.0 / self.config.tf_rate
        timer = self.rospy.Timer(self.rospy.Duration(period / 2), self._republish_map_odom, reset=True)
        threading.Thread(target=self._decode_loop, name="decode", daemon=True).start()
        while not self.rospy.is_shutdown():
            item = self.frames.take(timeout=period)
            self.control.apply_params()
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
            pipeline = self.control.pipeline  # its params (jpeg_reduce) may change: read once per image
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

    def _static_tf(self, child: str) -> np.ndarray:
        """base_link → ``child`` from tf (4×4); ``LookupError`` while tf does not have it."""
        c = self.config
        try:
            tr = self.tf_buffer.lookup_transform(c.base_frame, child, self.rospy.Time(0))
            return self.cv.transform_to_matrix(tr.transform, f"{c.base_frame}->{child}")
        except (self.tf2_ros.TransformException, self.cv.ConversionError) as e:
            raise LookupError(str(e)) from e

    def _odom_T_base(self, stamp) -> Optional[np.ndarray]:
        """odom→base_link at ``stamp``, waiting up to ~tf_timeout (wall clock) for it to arrive."""
        c, error = self.config, self.control.error
        deadline = time.monotonic() + c.tf_timeout
        while True:
            try:
                tr = self.tf_buffer.lookup_transform(c.odom_frame, c.base_frame, stamp)
                break
            except self.tf2_ros.ExtrapolationException as e:
                if time.monotonic() < deadline:
                    time.sleep(0.002)
                    continue
                error("tf_failures", f"tf {c.odom_frame} -> {c.base_frame} at the image time: {e}")
                return None
            except self.tf2_ros.TransformException as e:
                error("tf_failures", f"tf {c.odom_frame} -> {c.base_frame}: {e}")
                return None
        try:
            return self.cv.transform_to_matrix(tr.transform, f"tf {c.odom_frame}->{c.base_frame}")
        except self.cv.ConversionError as e:
            error("tf_nan", str(e))
            return None

    def _process(self, msg, received_wall: float, image, decode_ms: float) -> None:
        """One decoded image (``image``: the grey frame, or why the message gave none)."""
        ctl, stamp = self.control, msg.header.stamp
        s = self.cv.stamp_to_sec(stamp)
        if not ctl.take_image(s):
            return
        self.diag_image_age.tick(s)
        ctl.feed_prisms()
        if not ctl.ensure_pipeline(self._static_tf):
            return
        if isinstance(image, str):
            ctl.error("bad_images", image)
            return
        tf_wait = time.monotonic()
        odom_T_base = self._odom_T_base(stamp)
        if odom_T_base is None:
            return
        tf_wait_ms = 1e3 * (time.monotonic() - tf_wait)
        ctl.feed_prisms()  # what arrived while waiting for tf
        result = ctl.process_frame(s, image, odom_T_base)
        if result is None:
            return
        self.diag_images.tick()
        publish_start = time.perf_counter()
        self._publish(result, stamp, odom_T_base)
        self.health.latencies_ms.append(1e3 * (time.monotonic() - received_wall))
        publish_ms = 1e3 * (time.perf_counter() - publish_start)
        debug_start = time.perf_counter()
        self._publish_debug(msg, image, result)
        self.health.add_stages({"debug image": 1e3 * (time.perf_counter() - debug_start)})
        ctl.after_frame(s, result, odom_T_base)
        self.health.add_stages(result.timings)  # its decode: checking the decoded frame
        self.health.add_stages({"decode": decode_ms, "publish": publish_ms, "tf wait": tf_wait_ms})

    # ------------------------------------------------------------------ outputs
    def _publish(self, result: FrameResult, stamp, odom_T_base: np.ndarray) -> None:
        cv, c = self.cv, self.config
        self.pub_detections.publish(cv.observations_msg(result.observations, stamp, c.camera_frame))
        if self.control.map_refused:  # nothing that depends on the marker map: the detections, the prism's pose
            prism_pose = cv.prism_pose_msg(result, stamp, c.map_frame)
            if prism_pose is not None:
                self.pub_prism_pose.publish(prism_pose)
            return
        if result.map_T_odom is not None:
            self.control.send_estimate(result, cv.stamp_to_sec(stamp), self._send_map_odom)
        if has_marker_yaw(result):
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
            map_T_camera = (result.map_T_base @ self.control.pipeline.base_T_camera if result.map_T_base is not None
                            else None)
            frame = debug_frame(image, result.observations, self.marker_map, map_T_camera, int(c.debug_width))
            jpeg = encode_debug_jpeg(frame) if jpeg_wanted else b""
        except (DebugImageError, ValueError) as e:
            self.control.error("debug_image", f"~debug_image: {e}")
            return
        if jpeg_wanted:
            self.pub_debug.publish(self.cv.compressed_image(jpeg, msg.header.stamp, c.camera_frame))
        if raw_wanted:
            self.pub_debug_raw.publish(self.cv.bgr_image(frame, msg.header.stamp, c.camera_frame))

    def _send_map_odom(self, stamp_sec: float, map_T_odom: np.ndarray) -> None:
        """Broadcast ``map_T_odom`` at ``stamp_sec`` (s, already future-dated; the control decided it goes out)."""
        c = self.config
        self.tf_broadcaster.sendTransform(
            self.cv.matrix_to_transform_stamped(map_T_odom, self.cv.sec_to_stamp(stamp_sec), c.map_frame, c.odom_frame))
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
        in_use = self.control.republish(s, self._send_map_odom)
        if in_use is None:  # not initialised (or just reset)
            return
        if s > self._odometry_stamp and self.pub_odometry.get_num_connections():
            self._odometry_stamp = s
            self._publish_odometry(latest, *in_use)

    def _publish_odometry(self, latest, prediction, offset: float) -> None:
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

    def _pipeline_task(self, stat):
        """diagnostic_updater task ``pipeline``: :meth:`NodeControl.pipeline_status`."""
        return self.cv.fill_diagnostic(stat, *self.control.pipeline_status(
            time.monotonic(), self.images.received, self.images.dropped + self.frames.dropped))

    def _mapcheck_task(self, stat):
        """diagnostic_updater task ``map check``: does the marker map fit what the camera sees (error when not)."""
        return self.cv.fill_diagnostic(stat, *self.control.mapcheck_status())

    def _selfcheck_task(self, stat):
        """diagnostic_updater task ``self-check``: the rolling self-checks (time offset, tilt, moved marker)."""
        level, message, values = self.control.selfcheck_status(time.monotonic())
        return self.cv.fill_diagnostic(stat, level, message or "not enough observations yet", values)


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
