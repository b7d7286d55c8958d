"""Node ``ms60_driver``: a Leica MS60 (GeoCOM) tracking a prism → ``ms60/prism``.

In: the node's private parameters (the serial or TCP port, rate, timeouts, the station, ``~origin``, the
accuracy class, the re-aim's ``~predict``, ``~predict_max_age`` and ``~turn_rate_deg_s``) and tf (the robot's
fused pose and the prism's lever arm, for the re-aim after a lost lock). Out: ``ms60/prism`` (PointStamped,
stamped with the instrument's measurement time mapped to ROS time, never the reception time),
``ms60/prism_with_covariance`` (its covariance from the accuracy class and the polar geometry),
``ms60/status`` and ``/diagnostics``, and optionally a prism log. A bad parameter ends the node with one line
and exit status 2, a missing master with exit status 1, a master with ``/use_sim_time`` with 2. Every topic,
parameter and status key: doc/ros_api.md.
"""

from __future__ import annotations

import json
import math
from typing import Any, Dict, Optional, Tuple

import diagnostic_updater
import numpy as np
import rospy
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import PointStamped, PoseWithCovarianceStamped

from ..errors import ConfigurationError
from ..geocom.accuracy import MS60_TRACKING, AccuracyError, InstrumentAccuracy
from ..geocom.client import default_byte_timing
from ..geocom.tracker import (
    Ms60Tracker,
    PrismSample,
    TrackerConfig,
    TrackerError,
    TrackerState,
    TrackerStats,
    extrapolate,
)
from . import exit_without_master, run_node

__all__ = ["config_from_params", "output_from_params", "prediction_from_params", "extrapolate", "prism_with_covariance",
           "log_line", "stats_to_json", "status_values", "main"]


def _number(params: Dict[str, Any], name: str, default=None, kind=float, prefix: str = ""):
    value = params.get(name, default)
    name = prefix + name
    if value is None:
        return None
    integral = isinstance(value, (int, float)) and float(value).is_integer()
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (kind is int and not integral):
        raise TrackerError(f"~{name}: expected {'an integer' if kind is int else 'a number'}, got {value!r}")
    if not math.isfinite(float(value)):
        raise TrackerError(f"~{name}: {value!r} is not finite")
    return kind(value)


def config_from_params(params: Dict[str, Any]) -> Tuple[TrackerConfig, str]:
    """Tracker settings and frame id from the node's private parameters (a dict as returned by
    ``rospy.get_param("~")``). Raises TrackerError naming the parameter."""
    port = params.get("port", "/dev/ttyUSB0")
    if not isinstance(port, str) or not port.strip():
        raise TrackerError(f"~port: expected a pyserial URL such as /dev/ttyUSB0 or socket://host:port, got {port!r}")
    frame_id = params.get("frame_id", "map")
    if not isinstance(frame_id, str) or not frame_id.strip():
        raise TrackerError(f"~frame_id: expected a frame name, got {frame_id!r}")
    baud = _number(params, "baud", 115200, int)
    if baud not in (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600):
        raise TrackerError(f"~baud: {baud} is not a standard baud rate (115200 for 20 Hz)")
    rate = _number(params, "rate", 20.0)
    if not 0 < rate <= 100:
        raise TrackerError(f"~rate: {rate} Hz is not in (0, 100]")
    timeout = _number(params, "timeout", 0.3)
    if not 0 < timeout <= 10:
        raise TrackerError(f"~timeout: {timeout} s is not in (0, 10]")
    motion_timeout = _number(params, "motion_timeout", 30.0)
    if not 5 <= motion_timeout <= 300:
        raise TrackerError(f"~motion_timeout: {motion_timeout} s is not in [5, 300] (a PowerSearch takes seconds)")
    byte_timing = params.get("byte_timing", default_byte_timing(port))
    if not isinstance(byte_timing, bool):
        raise TrackerError(f"~byte_timing: expected true or false, got {byte_timing!r}")
    prism_mm = _number(params, "prism_constant_mm")
    if prism_mm is not None and not -1000 < prism_mm < 1000:
        raise TrackerError(f"~prism_constant_mm: {prism_mm} mm is not within ±1000 mm")
    min_latency_ms = _number(params, "min_latency_ms", 0.0)
    if not 0 <= min_latency_ms <= 1000:
        raise TrackerError(f"~min_latency_ms: {min_latency_ms} ms is not in [0, 1000]")
    accuracy = _accuracy(params.get("accuracy", {}))
    turn_rate = _number(params, "turn_rate_deg_s", 90.0)
    if not 1 <= turn_rate <= 1000:
        raise TrackerError(f"~turn_rate_deg_s: {turn_rate} °/s is not in [1, 1000]")
    station_params = params.get("station", {})
    if not isinstance(station_params, dict):
        raise TrackerError(f"~station: expected a dictionary with x, y, z, instrument_height, orientation_deg, "
                           f"got {station_params!r}")
    unknown = set(station_params) - {"x", "y", "z", "instrument_height", "orientation_deg"}
    if unknown:
        raise TrackerError(f"~station: unknown key(s) {', '.join(sorted(unknown))}")
    xyz = [_number(station_params, k, prefix="station/") for k in ("x", "y", "z")]
    station = None
    if any(v is not None for v in xyz):
        if any(v is None for v in xyz):
            raise TrackerError("~station: x, y and z must be given together")
        hi = _number(station_params, "instrument_height", 0.0, prefix="station/")
        station = (xyz[0], xyz[1], xyz[2], hi)
    orientation_deg = _number(station_params, "orientation_deg", prefix="station/")
    config = TrackerConfig(
        url=port.strip(), baud=baud, rate_hz=rate, timeout_s=timeout, motion_timeout_s=motion_timeout,
        byte_timing=byte_timing,
        prism_constant_m=None if prism_mm is None else prism_mm / 1000.0, station=station,
        orientation_rad=None if orientation_deg is None else math.radians(orientation_deg),
        min_latency_s=min_latency_ms / 1000.0, accuracy=accuracy, turn_rate_deg_s=turn_rate)
    config.validate()
    return config, frame_id.strip()


def _accuracy(params) -> InstrumentAccuracy:
    """``~accuracy/*`` → InstrumentAccuracy (defaults: the MS60's). Raises TrackerError naming the parameter."""
    if not isinstance(params, dict):
        raise TrackerError(f"~accuracy: expected a dictionary with {', '.join(MS60_TRACKING._fields)}, got {params!r}")
    unknown = set(params) - set(MS60_TRACKING._fields)
    if unknown:
        raise TrackerError(f"~accuracy: unknown key(s) {', '.join(sorted(unknown))}; expected "
                           f"{', '.join(MS60_TRACKING._fields)}")
    accuracy = MS60_TRACKING._replace(**{k: _number(params, k, prefix="accuracy/") for k in params})
    try:
        return accuracy.validate()
    except AccuracyError as e:
        raise TrackerError(f"~accuracy/{e}") from None


def output_from_params(params: Dict[str, Any]) -> Tuple[Tuple[float, float, float], Optional[str]]:
    """``(origin (E, N, H), log path or None)`` from the private parameters ``~origin`` and ``~log``.
    Raises TrackerError naming the parameter."""
    origin = params.get("origin", [0.0, 0.0, 0.0])
    if (not isinstance(origin, (list, tuple)) or len(origin) != 3
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in origin)):
        raise TrackerError(f"~origin: expected [E, N, H] in metres (the marker map's origin), got {origin!r}")
    log = params.get("log", "")
    if not isinstance(log, str):
        raise TrackerError(f"~log: expected a file path, got {log!r}")
    return (float(origin[0]), float(origin[1]), float(origin[2])), (log.strip() or None)


def prism_with_covariance(point: PointStamped, cov) -> PoseWithCovarianceStamped:
    """The position of ``point`` with its covariance ``cov`` (3×3 m²); the orientation unobserved (variance 1e6,
    conversions.UNOBSERVED_VARIANCE: that module needs the package's messages, this node does not)."""
    msg = PoseWithCovarianceStamped(header=point.header)
    msg.pose.pose.position = point.point
    msg.pose.pose.orientation.w = 1.0
    C = np.diag([0.0] * 3 + [1.0e6] * 3)
    C[:3, :3] = 0.5 * (np.asarray(cov, dtype=float) + np.asarray(cov, dtype=float).T)
    msg.pose.covariance = [float(x) for x in C.ravel()]
    return msg


def prediction_from_params(params: Dict[str, Any]) -> Tuple[bool, str, float]:
    """``(predict, prism frame, max age s)`` from ``~predict``, ``~prism_frame``, ``~predict_max_age``. Raises
    TrackerError naming the parameter."""
    predict = params.get("predict", True)
    if not isinstance(predict, bool):
        raise TrackerError(f"~predict: expected true or false, got {predict!r}")
    frame = params.get("prism_frame", "prism")
    if not isinstance(frame, str) or not frame.strip():
        raise TrackerError(f"~prism_frame: expected a frame name, got {frame!r}")
    max_age = _number(params, "predict_max_age", 1.0)
    if not 0 < max_age <= 10:
        raise TrackerError(f"~predict_max_age: {max_age} s is not in (0, 10]")
    return predict, frame.strip(), max_age


LOG_HEADER = "t,east,north,height\n"


def log_line(sample: PrismSample) -> str:
    """One ``~log`` row: stamp (s, ROS time) and the position in full coordinates (0.01 mm)."""
    return f"{sample.stamp_s:.6f},{sample.east:.5f},{sample.north:.5f},{sample.height:.5f}\n"


def stats_to_json(stats: TrackerStats) -> str:
    """The ``ms60/status`` JSON text (drift in ppm; NaN as null)."""
    d = stats._asdict()
    d["clock_drift_ppm"] = None if math.isnan(stats.clock_drift) else stats.clock_drift * 1e6
    del d["clock_drift"]
    d["clock_offset_s"] = None if math.isnan(stats.clock_offset_s) else stats.clock_offset_s
    d["edm_period_ms"] = None if math.isnan(stats.edm_period_ms) else stats.edm_period_ms
    d["warnings"] = {str(k): v for k, v in stats.warnings.items()}
    d["no_position"] = {str(k): v for k, v in stats.no_position.items()}
    return json.dumps(d, sort_keys=True)


def _diagnostics(status: DiagnosticStatus, stats: TrackerStats, rate_hz: float) -> DiagnosticStatus:
    """Fill ``status`` (diagnostic_updater's wrapper) from the tracker's figures: the lock state and the link."""
    if stats.state == "error":
        status.level, status.message = DiagnosticStatus.ERROR, stats.error
    elif stats.state in ("connecting", "reconnecting", "stopped"):
        status.level, status.message = DiagnosticStatus.ERROR, f"no link to the instrument ({stats.state})"
    elif stats.state != "locked":
        status.level = DiagnosticStatus.WARN
        status.message = f"prism not locked ({stats.state})" + (f": {stats.notice}" if stats.notice else "")
    elif stats.rate_hz < 0.9 * rate_hz:
        status.level, status.message = DiagnosticStatus.WARN, f"locked, slow: {stats.rate_hz:.1f} Hz"
    else:
        status.level, status.message = DiagnosticStatus.OK, f"locked, {stats.rate_hz:.1f} Hz"
    values = json.loads(stats_to_json(stats))
    status.values = [KeyValue(key=k, value=v if isinstance(v, str) else json.dumps(v))
                     for k, v in sorted(values.items())]
    return status


def status_values(status) -> dict:
    """The figures of a ``prism tracking`` status (``ms60/status`` or ``/diagnostics``) as :func:`stats_to_json`'s
    object: numbers, null and per-code counts parsed back, text as it is."""
    out = {}
    for kv in status.values:
        try:
            out[kv.key] = json.loads(kv.value)
        except ValueError:
            out[kv.key] = kv.value
    return out


SIM_TIME_MESSAGE = ("/use_sim_time is true on this master (a bag replay such as postprocess.launch "
                    "left it set); a live instrument is stamped with wall-clock time: run "
                    "`rosparam set /use_sim_time false` and start the driver again")


def _tf_prediction(frame_id: str, prism_frame: str, origin, max_age: float):
    """``predict(t)`` for the tracker: the prism's position at ROS time ``t`` (instrument coordinates) from tf, or
    None."""
    import tf2_ros

    buffer = tf2_ros.Buffer(cache_time=rospy.Duration(10.0))
    tf2_ros.TransformListener(buffer)

    def position(stamp) -> Tuple[float, np.ndarray]:
        tr = buffer.lookup_transform(frame_id, prism_frame, stamp)
        p = tr.transform.translation
        return tr.header.stamp.to_sec(), np.array([p.x, p.y, p.z])

    def predict(at_s: float) -> Optional[Tuple[float, float, float]]:
        try:
            newer = position(rospy.Time(0))
        except tf2_ros.TransformException:  # no pose of the robot (yet)
            return None
        try:
            older = position(rospy.Time.from_sec(newer[0] - 0.2))
        except tf2_ros.TransformException:  # one pose only: no velocity
            older = newer
        p = extrapolate(older, newer, rospy.get_time(), max_age, at_s)
        return None if p is None else tuple(float(x) for x in p + np.asarray(origin))

    return predict


def main() -> int:
    """Node entry point: track until shutdown; 2 (one line) for bad parameters, sim time or a log it cannot write."""
    exit_without_master("ms60_driver", "ms60.launch")
    rospy.init_node("ms60_driver")
    return run_node("ms60_driver", _drive)


def _drive() -> None:
    if rospy.get_param("/use_sim_time", False):
        raise ConfigurationError(SIM_TIME_MESSAGE)
    config, frame_id = config_from_params(rospy.get_param("~", {}))
    origin, log_path = output_from_params(rospy.get_param("~", {}))
    predict, prism_frame, max_age = prediction_from_params(rospy.get_param("~", {}))
    log = None
    if log_path:
        try:
            log = open(log_path, "a", buffering=1)  # noqa: SIM115 (open while the node spins, closed after)
            if log.tell() == 0:
                log.write(LOG_HEADER)
        except OSError as e:
            raise ConfigurationError(f"~log: cannot write {log_path}: {e.strerror}") from None
    prism_pub = rospy.Publisher("ms60/prism", PointStamped, queue_size=50)
    cov_pub = rospy.Publisher("ms60/prism_with_covariance", PoseWithCovarianceStamped, queue_size=50)
    status_pub = rospy.Publisher("ms60/status", DiagnosticStatus, queue_size=5, latch=True)
    updater = diagnostic_updater.Updater()
    updater.setHardwareID(f"MS60 {config.url}")
    positions = diagnostic_updater.HeaderlessTopicDiagnostic(
        "prism positions", updater, diagnostic_updater.FrequencyStatusParam({"min": config.rate_hz,
                                                                            "max": config.rate_hz}, 0.1, 5))
    stamp_offset = diagnostic_updater.TimeStampStatus(
        diagnostic_updater.TimeStampStatusParam(-0.1, config.timeout_s), "prism stamp offset")
    updater.add(stamp_offset)
    updater.add("prism tracking", lambda stat: _diagnostics(stat, tracker.stats(), config.rate_hz))

    def on_sample(sample: PrismSample) -> None:
        msg = PointStamped()
        # instrument time → host wall time (clock fit) = ROS time (sim time is refused at start-up)
        msg.header.stamp = rospy.Time.from_sec(sample.stamp_s)
        msg.header.frame_id = frame_id
        msg.point.x, msg.point.y, msg.point.z = (sample.east - origin[0], sample.north - origin[1],
                                                 sample.height - origin[2])
        prism_pub.publish(msg)
        cov_pub.publish(prism_with_covariance(msg, sample.cov))
        positions.tick()
        stamp_offset.tick(sample.stamp_s)
        if log is not None:
            log.write(log_line(sample))

    def on_state(state: TrackerState) -> None:
        if state == TrackerState.ERROR:
            rospy.logerr(f"ms60_driver: error: {tracker.error}")
        else:
            rospy.loginfo(f"ms60_driver: {state.value} ({config.url})")

    tracker = Ms60Tracker(config, on_sample=on_sample, on_state=on_state,
                          predict=_tf_prediction(frame_id, prism_frame, origin, max_age) if predict else None)

    def report(_event) -> None:
        stats = tracker.stats()
        if stats.state in ("connecting", "reconnecting"):
            rospy.logwarn_throttle(10.0, f"ms60_driver: no answer from the instrument on {config.url} ({stats.state})")
        if stats.instrument:
            updater.setHardwareID(stats.instrument)
        status_pub.publish(_diagnostics(DiagnosticStatus(name=f"{rospy.get_name().lstrip('/')}: prism tracking",
                                                         hardware_id=stats.instrument or f"MS60 {config.url}"),
                                        stats, config.rate_hz))
        updater.force_update()

    rospy.loginfo(f"ms60_driver: {config.url} at {config.baud} baud, {config.rate_hz} Hz, frame {frame_id}")
    tracker.start()
    timer = rospy.Timer(rospy.Duration(1.0), report)
    rospy.spin()
    timer.shutdown()
    tracker.stop()
    if log is not None:
        log.close()
