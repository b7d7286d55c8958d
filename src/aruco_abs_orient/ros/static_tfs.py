"""Static lever-arm transforms from a calibration YAML, published on /tf_static (node ``static_tfs``).

The calibration file (written by the calibration tool, doc/design.md §11) holds the camera's and the prism's
pose on the platform, in metres and degrees::

    base_link_to_camera: {xyz: [0.10, 0.00, 0.45], rpy_deg: [0.0, 0.0, 0.3]}   # rpy: R = Rz·Ry·Rx
    base_link_to_prism:  {xyz: [-0.05, 0.00, 0.62]}                          # rpy_deg optional (0)

Each entry is the transform ``base_link_T_child`` (child coordinates into base_link): the translation is
the child's origin in base_link, the rotation its axes. Private params: ``~calibration`` (path, required),
``~base_frame`` (base_link), ``~camera_frame`` (camera), ``~prism_frame`` (prism). A missing or malformed
file → one line naming the file and the key, exit status 2.
"""

from __future__ import annotations

import sys

from ..calibration import CalibrationError, load_calibration
from . import run_node

__all__ = ["main"]

def main(argv=None) -> int:
    """Node entry point: publish the two static transforms (latched) and spin; 2 (one line) for a bad file."""
    return run_node("static_tfs", lambda: _publish(argv))


def _publish(argv) -> int:
    import rospy
    import tf2_ros

    from . import exit_without_master

    exit_without_master("static_tfs", "live.launch", argv)
    from .conversions import matrix_to_transform_stamped

    rospy.init_node("static_tfs", argv=argv)
    path = rospy.get_param("~calibration", "")
    frames = {"camera": rospy.get_param("~camera_frame", "camera"),
              "prism": rospy.get_param("~prism_frame", "prism")}
    base = rospy.get_param("~base_frame", "base_link")
    if not path:
        raise CalibrationError("~calibration: no calibration file given (param ~calibration)")
    calibration = load_calibration(path)
    stamp = rospy.Time.now()
    msgs = [matrix_to_transform_stamped(calibration[child], stamp, base, frames[child])
            for child in ("camera", "prism")]
    tf2_ros.StaticTransformBroadcaster().sendTransform(msgs)
    rospy.loginfo(f"static_tfs: {base} -> {frames['camera']}, {base} -> {frames['prism']} from {path}")
    rospy.spin()
    return 0


if __name__ == "__main__":
    sys.exit(main())
