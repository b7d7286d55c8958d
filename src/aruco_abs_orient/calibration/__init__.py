"""Boresight, lever-arm, lens and time-offset calibration of the 360° camera from a recording.

In: a recording's marker observations (time, id, camera-frame bearing, σ), the odometry, the prism
track, the marker map, the nominal lever arms and lenses. Out: the camera's boresight rotation in
base_link (and optionally its lever arm, its two lenses' offset and relative rotation, the residual time
offset and the rolling-shutter readout) with their σ, written as the static-tf YAML the launch files
read. The observation model and its observability are described in ``problem``; the least squares in
``solve``; the files in ``io``; the types in ``model``.
"""

from .io import CALIBRATION_KEYS, launch_snippet, load_calibration, static_tf_yaml, write_static_tf_yaml
from .model import HEADING_MODELS, Calibration, CalibrationError, CalibrationParams, Recording, Unknowns
from .solve import calibrate

__all__ = [
    "HEADING_MODELS",
    "CalibrationError",
    "CalibrationParams",
    "Calibration",
    "Recording",
    "Unknowns",
    "calibrate",
    "static_tf_yaml",
    "write_static_tf_yaml",
    "launch_snippet",
    "load_calibration",
    "CALIBRATION_KEYS",
]
