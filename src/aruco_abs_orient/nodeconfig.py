"""The abs_orient node's configuration: its private parameters, read through any ``get_param``.

In: ``get_param(name, default)`` (``rospy.get_param``, or a dict's lookup in a test): the node's own parameters
``~markers`` … ``~north`` (:class:`NodeConfig`, each declared with its meaning, unit and range), the tunables as
namespaces ``~pipeline/…`` … ``~timesync/…`` (cfg/params.yaml's sections but calibrate's, loaded by
``<rosparam file=...>``), and the calibration file. Out: a checked :class:`NodeConfig` with
:meth:`NodeConfig.tunables` and :meth:`NodeConfig.calibrated_lever_arms`, or :class:`NodeConfigError`: one line
naming the parameter (``~name`` or ``~section/name``), the file and the key. ROS-free; the node's
``time_offset`` is also in cfg/AbsOrient.cfg.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Dict, Optional

import numpy as np

from .calibration import CalibrationError, load_calibration
from .errors import ConfigurationError
from .north import NORTHS
from .params import SECTIONS, ParamsError, Tunables, parse_params
from .paramspec import Params, coerce, param

__all__ = ["NodeConfig", "NodeConfigError", "NODE_SECTIONS"]

#: the sections of cfg/params.yaml the node reads from its namespaces: all but calibrate's, whose name is the
#: node's own ``~calibration`` (the calibration file); the live self-checks' calibration model keeps its defaults
NODE_SECTIONS = tuple(section for section, _ in SECTIONS if section != "calibration")


class NodeConfigError(ConfigurationError):
    """A node parameter with a bad value: names the parameter."""


@dataclass
class NodeConfig(Params):
    """Private parameters of the node (names without ``~``). ``calibration``'s lever arms replace the static tfs
    ``base_link → camera/prism`` (a bag replayed with its uncalibrated /tf_static) and its
    ``camera_readout_ms`` (rolling shutter) is used: the camera driver stamps an image with the capture time of
    its MIDDLE row, row v of H at stamp + (v/H − ½)·readout. ``north``: ``true`` turns the marker map and the
    prism positions by the grid's meridian convergence (:mod:`aruco_abs_orient.north`; needs the map's ``grid``
    and ``origin``). The frequency status of map→odom expects ``tf_rate`` to ``max(tf_rate,
    expected_image_rate)``."""

    error = NodeConfigError

    markers: str = param("", "marker map YAML (required)")
    image_transport: str = param("compressed", "camera/image/compressed (JPEG) or camera/image (raw)",
                                 choices=("compressed", "raw"))
    time_offset: float = param(0.0, "camera stamps = true (total-station) time + offset", "s", -5.0, 5.0)
    estimate_time_offset: bool = param(True, "estimate the offset live (VO and marker yaws against the prism "
                                       "track's heading, in a background thread), shown in the diagnostics")
    apply_estimated_time_offset: bool = param(True, "use a confident live estimate that contradicts the offset in "
                                              "use (by more than 5 σ and 20 ms: a forgotten or wrong offset); a "
                                              "good offset is never replaced by a coarser one")
    calibration: str = param("", "calibration YAML of aruco-abs-orient calibrate (empty: the lever arms from tf, "
                             "a global shutter)")
    publish_tf: bool = param(True, "broadcast map → odom (false when an EKF owns it)")
    transform_tolerance: float = param(0.1, "map→odom estimated at time t is stamped t + this (future-dated, as "
                                       "amcl)", "s", 0.0)
    tf_rate: float = param(20.0, "re-publication rate of map → odom while no image is processed", "Hz", above=0.0)
    tf_timeout: float = param(0.05, "how long to wait for odom → base_link at an image stamp (wall clock)", "s",
                              above=0.0)
    time_jump_tolerance: float = param(0.5, "a stamp going back by more than this resets the node", "s", above=0.0)
    prism_timeout: float = param(1.0, "a prism older than this: the diagnostics warn (and the prism stamp offset's "
                                 "limit)", "s", above=0.0)
    image_timeout: float = param(2.0, "no image for this long (wall clock): the diagnostics warn", "s", above=0.0)
    diagnostics_rate: float = param(1.0, "rate of /diagnostics", "Hz", above=0.0)
    expected_image_rate: float = param(30.0, "the rate the frequency status of images processed expects", "Hz",
                                       above=0.0)
    expected_prism_rate: float = param(20.0, "the rate the frequency status of prism positions expects", "Hz",
                                       above=0.0)
    rate_tolerance: float = param(0.5, "tolerance of the frequency statuses, a fraction", "", 0.0, below=1.0)
    max_image_age: float = param(0.5, "an image older than this when processed (ROS time): its timestamp status "
                                 "errs", "s", above=0.0)
    debug_rate: float = param(2.0, "most ~debug_image frames per second (drawn only while subscribed)", "Hz",
                              above=0.0)
    debug_width: float = param(1920.0, "largest width of a ~debug_image frame", "px", 16.0, 16384.0)
    state_file: str = param("", "JSON file keeping the map→odom filter's state (written at most once a second); a "
                            "node started within state_max_age of it starts from it (empty: none)")
    state_max_age: float = param(10.0, "oldest state restored (ROS time: a bag replayed later never matches)", "s",
                                 above=0.0)
    map_frame: str = param("map", "the total station's frame")
    odom_frame: str = param("odom", "the odometry's frame")
    base_frame: str = param("base_link", "the platform's frame")
    camera_frame: str = param("camera", "the 360° camera's frame")
    prism_frame: str = param("prism", "the prism's frame")
    markers_only: bool = param(False, "no total station: each frame's pose from a resection on its markers, on "
                               "abs_orient/pose_markers (a map of fewer than 3 markers is refused)")
    imu_topic: str = param("", "sensor_msgs/Imu for roll and pitch (empty: none; the tilt from the markers and the "
                           "odometry)")
    north: str = param("grid", "what map's headings are referred to: grid (the marker map's y axis) or true "
                       "(geographic north at the map's origin)", choices=NORTHS)

    @classmethod
    def label(cls, name: str) -> str:
        return f"~{name}"

    @classmethod
    def from_params(cls, get_param) -> NodeConfig:
        """Read ``~name`` for every field and ``~section`` for every section of :data:`NODE_SECTIONS` through
        ``get_param(name, default)`` (rospy.get_param), and check them all (the calibration file is read here,
        once). Raises NodeConfigError naming the parameter."""
        kw = {}
        for f in fields(cls):
            try:
                kw[f.name] = coerce(get_param("~" + f.name, f.default), f.metadata["spec"], f.default)
            except ValueError as e:
                raise NodeConfigError(f"~{f.name}: {e}") from None
        config = cls(**kw)
        if not config.markers:
            raise NodeConfigError("~markers: no marker map given (a YAML file, see cfg/markers_example.yaml)")
        try:
            config._tunables = parse_params({s: get_param("~" + s, {}) for s in NODE_SECTIONS}, "~", ros=True)
        except ParamsError as e:
            raise NodeConfigError(str(e)) from None
        config._calibrated_lever_arms = config._read_calibration()
        return config

    def _read_calibration(self) -> Optional[Dict[str, np.ndarray]]:
        if not self.calibration:
            return None
        try:
            return load_calibration(self.calibration)
        except CalibrationError as e:
            raise NodeConfigError(f"~calibration: {e}") from None

    def calibrated_lever_arms(self) -> Optional[Dict[str, np.ndarray]]:
        """``{"camera": base_T_camera, "prism": base_T_prism, …}`` of ``calibration`` (None without one), as
        :func:`aruco_abs_orient.calibration.load_calibration` read it when the configuration was made."""
        return getattr(self, "_calibrated_lever_arms", None)

    def tunables(self) -> Tunables:
        """The tunables of the node's ``~section`` namespaces (the defaults where they are silent)."""
        return getattr(self, "_tunables", None) or parse_params({})
