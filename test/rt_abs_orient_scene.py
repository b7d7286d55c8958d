"""A live-fed scene for the abs_orient rostests and benches: a platform at a known pose in map, its
odometry, prism and rendered 360° frames published like a robot would (wall-clock stamps).

Truth: ``map_T_base`` and ``map_T_odom`` below; the marker map is abs_orient_scene_markers.yaml; the lever
arms are read from tf_static (published by the .test file), so every number has one source.
Images come from the synthetic renderer (camera.py's equirect model), JPEG-encoded.
"""
import os
import threading
import time

import numpy as np
import rospy
from cv_bridge import CvBridge
from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import CompressedImage, Image
from tf2_msgs.msg import TFMessage

from aruco_abs_orient.markers import MarkerMap
from aruco_abs_orient.ros.conversions import matrix_to_transform_stamped, transform_to_matrix
from aruco_abs_orient.synthetic.render import decode_jpeg, encode_jpeg, facing_marker, render_equirect
from aruco_abs_orient.transforms import invert_T, make_T, rpy_to_matrix, transform_points

HERE = os.path.dirname(os.path.abspath(__file__))
MARKERS = os.path.join(HERE, "abs_orient_scene_markers.yaml")
MAP_T_BASE = make_T(rpy_to_matrix(0.01, -0.005, 0.7), [0.2, -0.3, 0.1])
MAP_T_ODOM = make_T(rpy_to_matrix(0.0, 0.0, -0.4), [5.0, 2.0, 0.0])
ODOM_T_BASE = invert_T(MAP_T_ODOM) @ MAP_T_BASE
UNKNOWN_ID = 40  # not in the map


def lever_arms(tf_buffer, timeout=20.0):
    """(base_T_camera, base_T_prism) from tf_static."""
    out = []
    for child in ("camera", "prism"):
        tr = tf_buffer.lookup_transform("base_link", child, rospy.Time(0), rospy.Duration(timeout))
        out.append(transform_to_matrix(tr.transform))
    return tuple(out)


def render_frames(base_T_camera, width=960):
    """JPEG frames of the scene: 'good' (all markers), 'unknown' (marker 1 replaced by an id not in the
    map) and 'corrupt' (a JPEG header followed by garbage)."""
    mm = MarkerMap.load(MARKERS)
    cam_T_map = invert_T(MAP_T_BASE @ base_T_camera)
    frames = {}
    for name in ("good", "unknown"):
        placed = [facing_marker(UNKNOWN_ID if (name == "unknown" and m.id == 1) else m.id, m.size,
                                transform_points(cam_T_map, m.position)) for m in mm]
        frames[name] = encode_jpeg(render_equirect(width, placed, mm.dictionary, profile="realistic"), 85)
    frames["corrupt"] = b"\xff\xd8\xff\xe0" + bytes(np.random.default_rng(1).integers(0, 255, 5000, dtype=np.uint8))
    return frames


class Feed(threading.Thread):
    """Publishes odometry (tf), prism and image at ``rate`` Hz; switch inputs with the attributes
    ``image`` ('good' | 'unknown' | 'corrupt'), ``nan_tf`` and ``prism``."""

    def __init__(self, frames, base_T_prism, rate=10.0, raw=False):
        """``raw``: publish sensor_msgs/Image (mono8, decoded here) on camera/image instead of JPEG."""
        super().__init__(daemon=True)
        self.frames, self.rate = frames, rate
        self.prism_map = transform_points(MAP_T_BASE, base_T_prism[:3, 3])
        self.image, self.nan_tf, self.prism = "good", False, True
        self.pub_tf = rospy.Publisher("/tf", TFMessage, queue_size=10)
        self.pub_prism = rospy.Publisher("ms60/prism", PointStamped, queue_size=10)
        self.raw = raw
        if raw:
            self.pub_image = rospy.Publisher("camera/image", Image, queue_size=2)
            self.raw_frames = {k: CvBridge().cv2_to_imgmsg(decode_jpeg(v), "mono8") for k, v in frames.items()
                               if k != "corrupt"}
        else:
            self.pub_image = rospy.Publisher("camera/image/compressed", CompressedImage, queue_size=2)
        self.stop = threading.Event()
        self.sent = 0
        self.sent_wall = {}  # image stamp (ns) -> time.monotonic() at publication (the last 1000)

    def run(self):
        period = 1.0 / self.rate
        while not self.stop.is_set() and not rospy.is_shutdown():
            tick = time.monotonic()
            now = rospy.Time.now()
            tr = matrix_to_transform_stamped(ODOM_T_BASE, now, "odom", "base_link")
            if self.nan_tf:
                tr.transform.translation.x = float("nan")
            self.pub_tf.publish(TFMessage([tr]))
            if self.prism:
                msg = PointStamped()
                msg.header.stamp, msg.header.frame_id = now, "map"
                msg.point.x, msg.point.y, msg.point.z = (float(v) for v in self.prism_map)
                self.pub_prism.publish(msg)
            if self.raw:
                img = self.raw_frames[self.image]
            else:
                img = CompressedImage(format="jpeg", data=self.frames[self.image])
            img.header.stamp, img.header.frame_id = now, "camera"
            self.sent_wall[now.to_nsec()] = time.monotonic()
            if len(self.sent_wall) > 1000:
                self.sent_wall.pop(next(iter(self.sent_wall)))
            self.pub_image.publish(img)
            self.sent += 1
            self.stop.wait(max(0.0, period - (time.monotonic() - tick)))
