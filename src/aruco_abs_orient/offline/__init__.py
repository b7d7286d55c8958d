"""offline: the post-processing commands (``process``, ``calibrate``, ``evaluate``, ...).

The package's ``__init__`` keeps OpenBLAS to one thread (``OPENBLAS_NUM_THREADS``): see there.
"""
