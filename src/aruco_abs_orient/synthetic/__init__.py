"""synthetic.

Importing this package before numpy sets ``OPENBLAS_NUM_THREADS=1`` unless the environment already sets
it, as :mod:`aruco_abs_orient.offline` does: the generator renders on one process per core, whose
OpenBLAS threads would only compete (the forkserver's workers inherit it even when the caller imported
numpy first). The realistic world's frames: 137 instead of 169 ms CPU each (bench/offline.py).
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
