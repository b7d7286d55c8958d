"""aruco_abs_orient: absolute orientation of mobile platforms from ArUco markers in 360° images.

The core (everything outside ``ros/``) never imports rospy and stays Python 3.8 compatible;
``offline/`` and ``synthetic/`` need Python >= 3.10 (rosbags).
"""

__version__ = "0.1.0"
