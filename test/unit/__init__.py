"""Unit tests, in folders mirroring src/aruco_abs_orient/ (test/unit/<package>/test_<module>.py).

The folders are packages so that two folders may hold test files of the same name (pytest's default
import mode names a test module by its package path, unit.<folder>.test_<module>).
"""
