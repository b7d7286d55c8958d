"""offline.

Importing this package before numpy sets ``OPENBLAS_NUM_THREADS=1`` unless the environment already sets
it: the pipeline's linear algebra is all 2×2–6×6 matrices, for which OpenBLAS's threads only cost (a 3×3
inverse of the filter took 2.5 ms instead of 9 µs on a busy 2-core machine) and take the core the JPEG
reader thread needs. ``process`` on the 24 s realistic rolling-shutter demo: 1.37× faster wall, 30 % less
CPU (bench/offline.py). Without effect when numpy was imported first.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
