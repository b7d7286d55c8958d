"""The abs_orient node's decisions without ROS: what a frame, a prism position or a reconfiguration does.

In (from ``ros/abs_orient_node.py``, which converts the messages): the node's :class:`NodeConfig`, the marker
map and north reference; per event an image stamp (s, camera clock) with its grey frame and odom→base_link
(4×4), prism positions (``prism_in``), IMU tilts (the ``imu_tilts`` deque), reconfigured values, the lever
arms once tf has them (``static_tf(child)``: 4×4 or ``LookupError``). Out: the :class:`FrameResult` to publish,
map→odom through the node's ``send(stamp, map_T_odom)`` at the stamps :class:`MapOdomStamps` allows, the
``pipeline``, ``self-check`` and ``map check`` statuses (level, message, values), the state file, resets
(``on_reset``: the node clears its tf buffer). Stamps are float seconds; ``*_wall`` are monotonic seconds.
``log``: anything with rospy's ``loginfo``/``logwarn``/``logerr``/``logwarn_throttle`` (rospy in the node).
Threads: ``tf_lock`` guards the stamp policy and the prediction (image thread, tf timer); the self-check and
the reconfigured values have their own locks; the map check runs in a worker thread.
"""

from __future__ import annotations

import collections
import json
import math
import os
import threading
import time
import traceback
from dataclasses import replace
from functools import cached_property
from typing import Callable, Deque, Dict, Mapping, Optional, Tuple

import numpy as np

from .errors import AbsOrientError
from .mapcheck import DOES_NOT_FIT, FITS, MapVerdict, RollingMapCheck
from .markers import MarkerMap
from .nodeconfig import NodeConfig
from .nodestate import (
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
from .north import NorthReference
from .pipeline import AbsOrientPipeline, FrameResult, PipelineError, all_param_fields
from .selfcheck import ModelContext, RollingSelfCheck, YawObservation
from .timesync import OnlineOffsetEstimator
from .transforms import yaw_of
from .tum import Trajectory, WriteError, atomic_write_text

__all__ = ["NodeControl", "RECONFIGURABLE_NODE_PARAMS", "reconfigurable_names", "has_marker_yaw"]

#: node-level entries of cfg/AbsOrient.cfg (all others are pipeline tunables, see all_param_fields)
RECONFIGURABLE_NODE_PARAMS = ("time_offset",)

Status = Tuple[str, str, Dict[str, object]]
Send = Callable[[float, np.ndarray], None]


def reconfigurable_names() -> Tuple[str, ...]:
    """Names cfg/AbsOrient.cfg may expose: the node's own plus every pipeline tunable."""
    return RECONFIGURABLE_NODE_PARAMS + tuple(name for _, name, _ in all_param_fields())


def has_marker_yaw(result: FrameResult) -> bool:
    """The frame has its own marker yaw (``fused_yaw``) from at least one accepted marker."""
    return result.fused_yaw is not None and any(r.accepted for r in result.observations)


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


class NodeControl:
    """The node's state and decisions (see the module's doc); ``ros_time()`` s: the ROS clock now;
    ``state_writer()``: {"node", "master", "run_id"} of this node (asked once, when a state file is used)."""

    def __init__(self, config: NodeConfig, marker_map: MarkerMap, north: NorthReference, log,
                 ros_time: Callable[[], float], state_writer: Callable[[], Dict[str, str]],
                 on_reset: Callable[[], None] = lambda: None):
        self.config, self.marker_map, self.north, self.log = config, marker_map, north, log
        self.ros_time, self._writer, self.on_reset = ros_time, state_writer, on_reset
        self.pipeline: Optional[AbsOrientPipeline] = None
        self.time_offset = config.time_offset
        self.time_offset_source = "parameter"
        self.offset_estimator: Optional[OnlineOffsetEstimator] = None  # made with the pipeline (lever arm)
        self._selfcheck_lock = threading.Lock()   # fed by the image thread, read by the diagnostics
        self.selfcheck = self._new_selfcheck()
        self._selfcheck_report: Status = ("ok", "", {})
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
        self.tf_lock = threading.Lock()  # the stamp policy and the prediction: image thread and tf timer
        self.prediction: Optional[MapOdomPrediction] = None  # of the filter, total-station time
        self.health = NodeHealth(config.image_timeout, config.prism_timeout, config.publish_tf, time.monotonic(),
                                 (config.base_frame, config.camera_frame, config.prism_frame))
        # inputs the callbacks leave for the image thread (bounded)
        self.prisms: Deque[Tuple[float, np.ndarray, Optional[np.ndarray]]] = collections.deque(maxlen=1000)
        self.prism_errors: Deque[str] = collections.deque(maxlen=100)
        self.imu_tilts: Deque[Tuple[float, float, float, float]] = collections.deque(maxlen=1000)
        self.last_prism_stamp: Optional[float] = None     # s, total-station clock
        self.last_image_wall = time.monotonic()
        self.initialised = False                          # the pipeline's filter, from the last good frame
        self.last_result: Optional[FrameResult] = None

    # ------------------------------------------------------------------ inputs
    def prism_in(self, t: float, p: np.ndarray, cov: Optional[np.ndarray]) -> None:
        """A prism position (s, m in the map; its covariance or None), turned to the north reference."""
        p, cov = self.north.turn_point(p, cov)
        self.prisms.append((t, p, cov))

    def reconfigured(self, values: Mapping[str, object]) -> None:
        """dynamic_reconfigure handed over every parameter (its thread): keep only what changed (a detection or
        tracking parameter rebuilds the tracker, which then searches the full frame once)."""
        with self._param_lock:
            for k in reconfigurable_names():
                if k in values and self._reconfigured.get(k) != values[k]:
                    self._pending_params[k] = self._reconfigured[k] = values[k]

    def apply_params(self) -> None:
        """Apply the reconfigured values (image thread); pipeline ones wait for the pipeline."""
        with self._param_lock:
            changes, self._pending_params = self._pending_params, {}
        if not changes:
            return
        if "time_offset" in changes:
            self.use_time_offset(float(changes.pop("time_offset")), "parameter")
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
            self.error("bad_params", f"parameters not applied: {e}")

    def error(self, key: str, text: str) -> None:
        """Count a problem under ``key`` (the ``pipeline`` status) and log it, at most every 5 s per key."""
        n = self.health.error(key, text)
        if self._throttle.due(key):
            self.log.logwarn(f"abs_orient: {text} ({n} so far)")

    def take_image(self, s: float) -> bool:
        """An image stamped ``s`` (s, camera clock) arrives: False when it is to be skipped (not after the previous
        one); a stamp that jumped back resets the node first."""
        self.last_image_wall = time.monotonic()
        with self.tf_lock:
            previous = self.stamps.last_image
            verdict = self.stamps.check_image(s)
        if verdict == IMAGE_JUMPED_BACK:
            self.reset(f"image time jumped back by {previous - s:.3f} s")
            with self.tf_lock:
                self.stamps.check_image(s)
        elif verdict == IMAGE_NOT_AFTER:
            self.error("out_of_order", f"image stamp {s:.3f} s not after the previous one, {previous:.3f} s")
            return False
        return True

    def feed_prisms(self) -> None:
        """The prism positions received so far to the pipeline and the checks (kept until the pipeline exists)."""
        while self.prism_errors:
            self.error("bad_prism", f"ms60/prism: {self.prism_errors.popleft()}")
        while self.prisms and self.pipeline is not None:
            t, p, cov = self.prisms.popleft()
            if self.stamps.jumped_back(self.last_prism_stamp, t):
                self.reset(f"ms60/prism time jumped back by {self.last_prism_stamp - t:.3f} s")
            self.last_prism_stamp = t if self.last_prism_stamp is None else max(t, self.last_prism_stamp)
            self.health.count("prisms")
            self.pipeline.add_prism(t, p, cov)
            if self.mapcheck is not None:
                self.mapcheck.add_prism(t, p)
            with self._selfcheck_lock:
                self.selfcheck.add_prism(t, p)
            if self.offset_estimator is not None:
                self.offset_estimator.add_track(t, float(p[0]), float(p[1]))

    def reset(self, why: str) -> None:
        """Forget the timeline (a clock jump): filter, tracking, prism history, stamps, checks; ``on_reset``."""
        self.log.logwarn(f"abs_orient: {why}: resetting (filter, tracking, prism history, tf buffer)")
        self.health.count("resets")
        if self.pipeline is not None:
            self.pipeline.reset()
        self.on_reset()
        self.last_prism_stamp = None
        with self.tf_lock:
            self.stamps.reset()
            self.prediction = None
        self.last_result = None
        self.initialised = False
        if self.offset_estimator is not None:
            self.offset_estimator.clear()
        with self._selfcheck_lock:
            self.selfcheck = self._new_selfcheck()

    # ------------------------------------------------------------------ the pipeline
    def ensure_pipeline(self, static_tf: Callable[[str], np.ndarray]) -> bool:
        """Make the pipeline once the lever arms are known (from ``~calibration``, else ``static_tf(child)``, which
        raises ``LookupError`` while tf does not have it); then start from the state file. False: not yet."""
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
                arms[child] = static_tf(child)
            except LookupError as e:
                self.error("no_static_tf", f"waiting for the static tf {c.base_frame} -> {child}: {e}")
                return False
        try:
            self._make_pipeline(arms[c.camera_frame], arms[c.prism_frame], calibrated)
        except PipelineError as e:
            self.error("no_static_tf", f"unusable lever arms from {source}: {e}")
            return False
        self._update_pipeline_params()
        camera, prism = arms[c.camera_frame][:3, 3].round(3), arms[c.prism_frame][:3, 3].round(3)
        self.log.loginfo(f"abs_orient: lever arms from {source}: camera at {camera} m, prism at {prism} m "
                         f"in {c.base_frame}")
        self.restore_state()
        return True

    def _make_pipeline(self, base_T_camera: np.ndarray, base_T_prism: np.ndarray, calibrated) -> None:
        """The pipeline on these lever arms (``calibrated``: the calibration file's, or None), and the checks and
        the time-offset estimator that need them."""
        c = self.config
        readout = 0.0 if calibrated is None else float(calibrated.get("readout", 0.0))  # rolling shutter, s
        kwargs = c.tunables().pipeline_kwargs()
        if c.markers_only:
            kwargs["params"] = replace(kwargs["params"], markers_only=True)
        self.pipeline = AbsOrientPipeline(self.marker_map, base_T_camera, base_T_prism,
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
            self.offset_estimator = OnlineOffsetEstimator(prism_in_base=base_T_prism[:3, 3],
                                                          params=c.tunables().timesync)

    def process_frame(self, s: float, image: np.ndarray, odom_T_base: np.ndarray) -> Optional[FrameResult]:
        """One grey frame stamped ``s`` (camera clock) with odom→base_link: the pipeline's result (None: the
        pipeline failed, counted), its problems counted."""
        while self.imu_tilts:  # IMU stamps are on the robot's (camera/VO) clock
            t_imu, roll, pitch, sigma = self.imu_tilts.popleft()
            self.pipeline.add_imu(t_imu - self.time_offset, roll, pitch, sigma)
        bad_before = self.pipeline.stats.get("bad_images", 0)
        try:
            result = self.pipeline.process_image(s - self.time_offset, image, odom_T_base)
        except Exception as e:  # the pipeline promises not to raise; a live robot must not stop if it does
            self.error("pipeline_exceptions", f"pipeline failed on the image at {s:.3f} s: {type(e).__name__}: {e}")
            if self.health.counts["pipeline_exceptions"] == 1:
                self.log.logerr("abs_orient: first pipeline failure, with traceback:\n" + traceback.format_exc())
            return None
        self.health.count("processed")
        if result.error:
            corrupt = self.pipeline.stats.get("bad_images", 0) > bad_before
            self.error("bad_images" if corrupt else "frame_errors", result.error)
        else:
            self.initialised = result.initialised
        unknown = result.tracking.rejected_unknown if result.tracking is not None else 0
        if unknown:
            self.health.count("unknown_ids", unknown)
        self.last_result = result
        return result

    def after_frame(self, s: float, result: FrameResult, odom_T_base: np.ndarray) -> None:
        """After the frame's outputs: the state file, the self-checks, the map check, the live time offset."""
        self.save_state(time.monotonic())
        self._feed_selfcheck(result, odom_T_base)
        self.check_map(time.monotonic())
        self._estimate_time_offset(s, odom_T_base, result)

    # ------------------------------------------------------------------ map -> odom
    def prediction_from(self, t: float) -> MapOdomPrediction:
        """The filter's prediction from time ``t`` (s, total-station time) on, for the tf timer."""
        (A, PA), (B, PB) = self.pipeline.map_T_odom(t), self.pipeline.map_T_odom(t + 1.0)
        return MapOdomPrediction(t, A, t + 1.0, B, (PA[0, 0], PB[0, 0]))

    def send_estimate(self, result: FrameResult, t_image: float, send: Send) -> None:
        """The frame's map→odom (its image stamp ``t_image``, s) through ``send`` when the stamp policy allows,
        and the prediction from it on for the timer."""
        prediction = self.prediction_from(result.stamp)
        with self.tf_lock:
            self.prediction = prediction
            self._send(self.stamps.for_estimate(t_image), result.map_T_odom, send)

    def republish(self, s: float, send: Send) -> Optional[Tuple[MapOdomPrediction, float]]:
        """The tf timer: the prediction at the newest odometry stamp ``s`` through ``send`` when one is due;
        (the prediction, the time offset) in use, or None before the filter (or after a reset)."""
        with self.tf_lock:
            if self.prediction is None:
                return None
            prediction, offset = self.prediction, self.time_offset
            stamp = self.stamps.republish(s)
            if stamp is not None:
                self._send(stamp, prediction.at(s - offset), send)
                self.health.count("tf_republished")
        return prediction, offset

    def _send(self, stamp_sec: Optional[float], map_T_odom: np.ndarray, send: Send) -> None:
        """``send`` map→odom at ``stamp_sec`` (None: held back, counted) unless tf is not ours or the map is
        refused. Called with ``tf_lock`` held."""
        if stamp_sec is None:
            self.health.count("tf_held_back")
            return
        if self.config.publish_tf and not self.map_refused:
            send(stamp_sec, map_T_odom)
            self.health.count("tf_published")

    # ------------------------------------------------------------------ self-checks and time offset
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

    def selfcheck_status(self, now_wall: float) -> Status:
        """The rolling self-checks, evaluated at most every 5 s (a fit over up to 120 s of observations)."""
        if now_wall - self._selfcheck_wall >= 5.0:
            self._selfcheck_wall = now_wall
            with self._selfcheck_lock:
                try:
                    self._selfcheck_report = self.selfcheck.diagnostics()
                except Exception as e:  # a check must never take the node down
                    self._selfcheck_report = ("ok", "", {"self-check note": f"{type(e).__name__}: {e}"})
        return self._selfcheck_report

    def _estimate_time_offset(self, s: float, odom_T_base: np.ndarray, result: FrameResult) -> None:
        """Feed the live estimator (camera clock ``s``); start an estimate when one is due; switch to a
        confident estimate that contradicts the offset in use."""
        est = self.offset_estimator
        if est is None:
            return
        est.add_vo(s, float(yaw_of(odom_T_base[:3, :3])))
        if has_marker_yaw(result):
            est.add_marker_yaw(s, result.fused_yaw)
        est.update_in_background(s)
        if not self.config.apply_estimated_time_offset:
            return
        with self._selfcheck_lock:
            better, vetoed = live_offset_to_apply(self.time_offset, est, self.selfcheck)
        if vetoed:
            self.health.count("time_offset_switch_refused")
            self.log.logwarn_throttle(30.0, f"abs_orient: keeping the time offset {self.time_offset:.4f} s: the "
                                            f"live estimate {est.applied:.4f} s contradicts it, but the marker yaws "
                                            "support it and contradict the estimate (self-check)")
        if better is not None:
            self.log.logwarn(f"abs_orient: time offset {self.time_offset:.4f} s -> {better:.4f} s "
                             f"(live estimate ± {1e3 * est.applied_sigma:.1f} ms contradicts the one in use)")
            self.use_time_offset(better, "live estimate")

    def use_time_offset(self, offset: float, source: str) -> None:
        """Switch to the time offset ``offset`` (s) from ``source``; the self-checks start afresh on it (their
        marker yaws so far were made with the old one, and they measure the error of the offset in use)."""
        self.time_offset, self.time_offset_source = offset, source
        with self._selfcheck_lock:
            self.selfcheck = self._new_selfcheck()

    # ------------------------------------------------------------------ state file
    @cached_property
    def state_writer(self) -> Dict[str, str]:
        """Who writes the state: this node's name, its master and the master's /run_id (a new roscore, a new id)."""
        return dict(self._writer())

    @cached_property
    def state_file(self) -> str:
        """``~state_file`` with the node's name and the master's port in its name (nodes of different masters never
        share one)."""
        return state_path(self.config.state_file, self.state_writer["node"], self.state_writer["master"])

    def restore_state(self) -> None:
        """Start the filter from ``~state_file`` when it is recent (a respawn while the robot drives)."""
        c = self.config
        if not c.state_file or not os.path.exists(self.state_file):
            return
        now = self.ros_time() - self.time_offset
        try:
            with open(self.state_file) as f:
                snap, why = state_snapshot(json.load(f), self.state_writer)
            why = why or self.pipeline.filter.restore(snap, now, c.state_max_age)
        except (OSError, ValueError) as e:
            why = f"cannot read it: {e}"
        if why:
            self.log.loginfo(f"abs_orient: not starting from {self.state_file}: {why}")
            return
        self.initialised = True
        prediction = self.prediction_from(now)  # the state predicted to now: map->odom goes out at once
        with self.tf_lock:
            self.prediction = prediction
        self.log.loginfo(f"abs_orient: started from the map->odom state in {self.state_file} "
                         f"({self.pipeline.filter.stats.restored_age:.2f} s old)")

    def save_state(self, now_wall: float) -> None:
        """Write the filter's state to ``~state_file`` (atomically, at most once a second)."""
        c = self.config
        if not c.state_file or now_wall - self._state_saved_wall < 1.0 or self.map_refused:
            return
        snap = self.pipeline.filter.snapshot() if self.pipeline is not None else None
        if snap is None:
            return
        self._state_saved_wall = now_wall
        try:
            atomic_write_text(self.state_file, json.dumps(state_record(snap, self.state_writer)) + "\n")
        except WriteError as e:
            self.error("state_file", f"~state_file {self.state_file}: cannot write: {e}")

    # ------------------------------------------------------------------ map check
    def check_map(self, now_wall: float) -> Optional[threading.Thread]:
        """Start the map check in a worker thread every 2 s (wall) until the map fits, then every 15 s (0.1-0.2 s of
        CPU each on 1000 sightings); it hands its verdict to :meth:`take_map_verdict`. Returns the thread started
        (None: none due)."""
        worker = self._mapcheck_worker
        if self.mapcheck is None or (worker is not None and worker.is_alive()):
            return None
        if now_wall - self._mapcheck_wall < (15.0 if self.map_verdict.status == FITS and not self.map_refused
                                             else 2.0):
            return None
        self._mapcheck_wall = now_wall

        def check():
            try:
                verdict = self.mapcheck.check()
            except Exception as e:  # a check must never take the node down
                verdict = MapVerdict("undetermined", f"the map check failed: {type(e).__name__}: {e}", {})
            self.take_map_verdict(verdict)

        self._mapcheck_worker = threading.Thread(target=check, name="map check", daemon=True)
        self._mapcheck_worker.start()
        return self._mapcheck_worker

    def take_map_verdict(self, verdict: MapVerdict) -> None:
        """A map that does not fit stops everything that depends on it, for good; later checks only say better how
        it is off (once its markers were seen from different places)."""
        if self.map_refused and verdict.status != DOES_NOT_FIT:
            return  # refused for good: a later window of sightings does not take it back
        self.map_verdict = verdict
        if verdict.status == DOES_NOT_FIT:
            first = not self.map_refused
            self.map_refused = verdict.message
            with self.tf_lock:
                self.prediction = None  # the timer stops re-publishing map->odom
            if first:
                self.log.logerr(f"abs_orient: {verdict.message}: map->odom, the absolute yaw and pose are no "
                                f"longer published (check ~markers {self.config.markers})")

    # ------------------------------------------------------------------ diagnostics
    def tilt_source(self) -> str:
        """Where the newest frame's roll and pitch came from (imu, markers, odometry), with unusable IMU samples."""
        r, unusable = self.last_result, self.health.counts["imu_unusable"]
        return ((r.tilt_source if r is not None and r.tilt_source else "-")
                + (f" ({unusable} IMU samples unusable)" if unusable else ""))

    def pipeline_status(self, now_wall: float, images_received: int, images_dropped: int) -> Status:
        """The ``pipeline`` status: :meth:`NodeHealth.report` since the previous one; an error once the map is
        refused."""
        r = self.last_result
        level, message, values = self.health.report(now_wall, self.ros_time(), NodeSnapshot(
            initialised=self.initialised, image_age_wall=now_wall - self.last_image_wall,
            last_prism_stamp=self.last_prism_stamp, prisms_waiting=bool(self.prisms),
            images_received=images_received, images_dropped=images_dropped, time_offset=self.time_offset,
            time_offset_source=self.time_offset_source, pipeline=self.pipeline, offset_estimator=self.offset_estimator,
            map_odom_yaw=float(yaw_of(r.map_T_odom[:3, :3])) if r is not None and r.map_T_odom is not None else None))
        if self.map_refused:
            level, message = "error", f"{self.map_refused}; map->odom not published"
        return level, message, values

    def mapcheck_status(self) -> Status:
        """The ``map check`` status: does the marker map fit what the camera sees (error when not)."""
        v = self.map_verdict
        values = {k: (json.dumps(x) if isinstance(x, (dict, list)) else x) for k, x in v.details.items()}
        return "error" if v.status == DOES_NOT_FIT else "ok", v.message, values
