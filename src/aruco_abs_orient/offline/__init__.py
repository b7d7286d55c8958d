"""offline.

Importing this package before numpy sets ``OPENBLAS_NUM_THREADS=1`` unless the environment already sets
it: the pipeline's linear algebra is all small matrices, for which OpenBLAS's threads only cost (a 3×3
inverse of the filter took 2.5 ms instead of 9 µs on a busy 2-core machine) and take the cores the JPEG
decoder threads need. ``process`` on the first 24 s of the realistic rolling-shutter demo: the solve stage
13 → 6 ms per frame, the whole run about a quarter less CPU (``bench/offline.py --speed``). Without effect
when numpy was imported first.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
