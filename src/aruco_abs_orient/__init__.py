"""aruco_abs_orient: absolute orientation of mobile platforms from ArUco markers in 360° images.

The core (everything outside ``ros/``) never imports rospy and stays Python 3.8 compatible;
``offline/`` and ``synthetic/`` need Python >= 3.10 (rosbags).

Importing the package before numpy sets ``OPENBLAS_NUM_THREADS=1`` unless the environment already sets it
(without effect when numpy was imported first). Its linear algebra is all small matrices, for which
OpenBLAS's threads only cost, and they spin while they wait:

- ``process`` on the first 24 s of the realistic rolling-shutter demo: the solve stage 13 → 6 ms per frame,
  the whole run about a quarter less CPU (``bench/offline.py --speed``); a 3×3 inverse of the filter took
  2.5 ms instead of 9 µs on a busy 2-core machine;
- the node replaying a bag at 4× real time (``test/abs_orient_consumer_bad.test``) used 1.6 of 2 cores,
  with the machine a third of its time in the kernel, and starved the robot's other processes: its
  map->odom reached them up to 0.4 s late. With one thread: 1.0 core, 8 % in the kernel.
"""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__version__ = "0.1.0"
