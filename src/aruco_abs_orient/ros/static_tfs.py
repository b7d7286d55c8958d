"""Static lever-arm transforms from a calibration YAML, published on /tf_static (node ``static_tfs``).

The calibration file (written by the calibration tool, DESIGN §4.8) holds the camera's and the prism's
pose on the platform, in metres and degrees::

    base_link_to_camera: {xyz: [0.10, 0.00, 0.45], rpy_deg: [0.0, 0.0, 0.3]}   # rpy: R = Rz·Ry·Rx
    base_link_to_prism:  {xyz: [-0.05, 0.00, 0.62]}                          # rpy_deg optional (0)

Each entry is the transform ``base_link_T_child`` (child coordinates into base_link): the translation is
the child's origin in base_link, the rotation its axes. Private params: ``~calibration`` (path, required),
``~base_frame`` (base_link), ``~camera_frame`` (camera), ``~prism_frame`` (prism). A missing or malformed
file → one line naming the file and the key, exit status 2.
"""

from __future__ import annotations

import math
import sys
from typing import Dict

import numpy as np

from ..transforms import make_T, rpy_to_matrix

__all__ = ["CalibrationError", "load_calibration", "main"]

KEYS = {"base_link_to_camera": "camera", "base_link_to_prism": "prism"}


class CalibrationError(ValueError):
    """A calibration YAML that cannot be used: the message names the file and the key."""


def _vector(entry: dict, key: str, where: str, default=None) -> np.ndarray:
    value = entry.get(key, default)
    if (not isinstance(value, (list, tuple)) or len(value) != 3
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value)):
        raise CalibrationError(f"{where}.{key}: expected [a, b, c] of finite numbers, got {value!r}")
    return np.array(value, dtype=float)


def load_calibration(path: str) -> Dict[str, np.ndarray]:
    """Read a calibration YAML → ``{"camera": base_T_camera, "prism": base_T_prism}`` (4×4, metres).
    Raises CalibrationError naming the file and the key."""
    import yaml

    try:
        with open(path) as f:
            data = yaml.safe_load(f)
    except OSError as e:
        raise CalibrationError(f"{path}: cannot read: {e.strerror}") from None
    except yaml.YAMLError as e:
        raise CalibrationError(f"{path}: not valid YAML: {e}") from None
    if not isinstance(data, dict):
        raise CalibrationError(f"{path}: expected a mapping with {' and '.join(KEYS)}")
    out = {}
    for key, child in KEYS.items():
        entry = data.get(key)
        where = f"{path}: {key}"
        if not isinstance(entry, dict):
            raise CalibrationError(f"{where}: missing; expected {{xyz: [x, y, z], rpy_deg: [r, p, y]}}")
        xyz = _vector(entry, "xyz", where)
        rpy = np.radians(_vector(entry, "rpy_deg", where, default=[0.0, 0.0, 0.0]))
        out[child] = make_T(rpy_to_matrix(*rpy), xyz)
    return out


def main(argv=None) -> int:
    """Node entry point: publish the two static transforms (latched) and spin."""
    import rospy
    import tf2_ros

    from .conversions import matrix_to_transform_stamped

    rospy.init_node("static_tfs", argv=argv)
    path = rospy.get_param("~calibration", "")
    frames = {"camera": rospy.get_param("~camera_frame", "camera"),
              "prism": rospy.get_param("~prism_frame", "prism")}
    base = rospy.get_param("~base_frame", "base_link")
    try:
        if not path:
            raise CalibrationError("~calibration: no calibration file given (param ~calibration)")
        calibration = load_calibration(path)
    except CalibrationError as e:
        rospy.logfatal(f"static_tfs: {e}")
        return 2
    stamp = rospy.Time.now()
    msgs = [matrix_to_transform_stamped(calibration[child], stamp, base, frames[child])
            for child in ("camera", "prism")]
    tf2_ros.StaticTransformBroadcaster().sendTransform(msgs)
    rospy.loginfo(f"static_tfs: {base} -> {frames['camera']}, {base} -> {frames['prism']} from {path}")
    rospy.spin()
    return 0


if __name__ == "__main__":
    sys.exit(main())
