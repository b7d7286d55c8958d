"""The calibration written and read back: the static-tf YAML, the launch snippet, the loader.

In: a :class:`~.model.Calibration` with the nominal ``base_T_camera`` and ``base_T_prism`` (4×4, m);
or the path of a calibration YAML. Out: the YAML text read by ``live.launch``/``postprocess.launch``
(``xyz`` in metres, ``rpy_deg`` in degrees, R = Rz(yaw)·Ry(pitch)·Rx(roll); the rolling shutter's readout
and the camera's two lenses when they are known), ``static_transform_publisher`` lines (tf2 argument order,
metres and radians), or all of it read back (:func:`load_calibration`, CalibrationError naming the file
and the key).
"""

from __future__ import annotations

import math
from typing import Dict, Tuple

import numpy as np

from ..camera import DualFisheye
from ..errors import ConfigurationError
from ..transforms import make_T, matrix_to_rpy, rpy_to_matrix
from ..tum import atomic_write_text, read_yaml
from .model import Calibration, CalibrationError

__all__ = ["CALIBRATION_KEYS", "READOUT_KEY", "LENSES_KEY", "static_tf_yaml", "write_static_tf_yaml", "launch_snippet",
           "load_calibration"]


def _camera_tf(calib: Calibration, base_T_camera_nominal) -> Tuple[np.ndarray, np.ndarray]:
    T = calib.apply(base_T_camera_nominal)
    return T[:3, 3], np.array(matrix_to_rpy(T[:3, :3]), dtype=float)


def static_tf_yaml(calib: Calibration, base_T_camera_nominal, base_T_prism) -> str:
    """The calibration YAML read by ``live.launch``/``postprocess.launch`` (``ros/static_tfs``):
    ``xyz`` in metres, ``rpy_deg`` in degrees with R = Rz(yaw)·Ry(pitch)·Rx(roll)."""
    xyz, rpy = _camera_tf(calib, base_T_camera_nominal)
    Tp = np.asarray(base_T_prism, dtype=float)
    rpy_p = np.array(matrix_to_rpy(Tp[:3, :3]), dtype=float)

    def vec(v, digits: int) -> str:
        return "[" + ", ".join(f"{float(x):.{digits}f}" for x in v) + "]"

    lines = [
        "# written by aruco-abs-orient calibrate",
        "# boresight (deg, in base_link, on top of the nominal mounting): "
        + ", ".join(f"{math.degrees(a):.4f} ± {math.degrees(s):.4f}"
                    for a, s in zip(calib.boresight_rpy, calib.boresight_sigma)),
        f"# bearing residual RMS: {math.degrees(calib.residual_rms_before):.4f} deg before, "
        f"{math.degrees(calib.residual_rms_after):.4f} deg after ({calib.n_used} observations, "
        f"{calib.n_markers} markers)",
        f"base_link_to_camera: {{xyz: {vec(xyz, 5)}, rpy_deg: {vec(np.degrees(rpy), 5)}}}",
    ]
    if calib.readout_estimated or calib.readout > 0:
        sigma = f" ± {1e3 * calib.readout_sigma:.3f}" if calib.readout_estimated else ""
        lines.insert(-1, f"# rolling shutter: row v of H is captured at the image stamp + (v/H - 1/2) * readout; "
                         f"readout {1e3 * calib.readout:.3f}{sigma} ms")
        lines.append(f"{READOUT_KEY}: {1e3 * max(calib.readout, 0.0):.4f}")   # a readout cannot be negative
    lenses = calib.lenses
    if calib.lenses_estimated or not lenses.single_centre:
        sigma = (f" ± {1e3 * calib.lens_offset_sigma:.3f} mm, rotation σ "
                 f"{vec(np.degrees(calib.lens_rotation_sigma), 4)} deg" if calib.lenses_estimated else "")
        lines.insert(-1, f"# two lenses: each centre {1e3 * lenses.lens_offset:.3f}{sigma}; stitched at "
                         f"{lenses.stitch_distance:g} m")
        stitch = ".inf" if math.isinf(lenses.stitch_distance) else f"{lenses.stitch_distance:g}"
        yaw_sigma = (f", yaw_sigma_deg: {vec(np.degrees(calib.lens_yaw_sigma), 5)}"
                     if np.all(np.isfinite(calib.lens_yaw_sigma)) else "")
        lines.append(f"{LENSES_KEY}: {{lens_offset_mm: {1e3 * lenses.lens_offset:.4f}, back_lens_rotation_deg: "
                     f"{vec(np.degrees(lenses.lens_rotation), 5)}, stitch_distance_m: {stitch}, "
                     f"blend_band_deg: {math.degrees(lenses.blend_band):g}, "
                     f"axis_azimuth_deg: {math.degrees(lenses.axis_azimuth):g}{yaw_sigma}}}")
    if np.any(np.abs(rpy_p) > 0):
        lines.append(f"base_link_to_prism: {{xyz: {vec(Tp[:3, 3], 5)}, rpy_deg: {vec(np.degrees(rpy_p), 5)}}}")
    else:
        lines.append(f"base_link_to_prism: {{xyz: {vec(Tp[:3, 3], 5)}}}")
    return "\n".join(lines) + "\n"


def write_static_tf_yaml(path: str, calib: Calibration, base_T_camera_nominal, base_T_prism) -> None:
    """Write :func:`static_tf_yaml` to ``path`` atomically."""
    atomic_write_text(path, static_tf_yaml(calib, base_T_camera_nominal, base_T_prism))


def launch_snippet(calib: Calibration, base_T_camera_nominal, base_T_prism, base_frame: str = "base_link",
                   camera_frame: str = "camera", prism_frame: str = "prism") -> str:
    """``static_transform_publisher`` lines for a launch file (tf2 argument order: x y z yaw pitch roll,
    metres and radians)."""
    xyz, rpy = _camera_tf(calib, base_T_camera_nominal)
    Tp = np.asarray(base_T_prism, dtype=float)
    rpy_p = np.array(matrix_to_rpy(Tp[:3, :3]), dtype=float)
    out = ["<!-- written by aruco-abs-orient calibrate -->"]
    for name, child, p, a in (("camera_tf", camera_frame, xyz, rpy), ("prism_tf", prism_frame, Tp[:3, 3], rpy_p)):
        args = " ".join(f"{float(x):.6f}" for x in (p[0], p[1], p[2], a[2], a[1], a[0]))
        out.append(f'<node pkg="tf2_ros" type="static_transform_publisher" name="{name}" '
                   f'args="{args} {base_frame} {child}"/>')
    return "\n".join(out) + "\n"


#: keys of the calibration YAML → the child frame each one places on base_link
CALIBRATION_KEYS = {"base_link_to_camera": "camera", "base_link_to_prism": "prism"}
#: key of the camera's rolling-shutter readout time (milliseconds; optional, 0 = global shutter)
READOUT_KEY = "camera_readout_ms"
#: key of the camera's two lenses (optional; ``camera.DualFisheye``: lens_offset_mm, back_lens_rotation_deg,
#: stitch_distance_m (.inf: at infinity), blend_band_deg, axis_azimuth_deg; and yaw_sigma_deg, each lens's yaw
#: 1-σ from the calibration: front, back)
LENSES_KEY = "camera_lenses"


def _vector(entry: dict, key: str, where: str, default=None) -> np.ndarray:
    value = entry.get(key, default)
    if (not isinstance(value, (list, tuple)) or len(value) != 3
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value)):
        raise CalibrationError(f"{where}.{key}: expected [a, b, c] of finite numbers, got {value!r}")
    return np.array(value, dtype=float)


def load_calibration(path: str) -> Dict[str, object]:
    """Read a calibration YAML → ``{"camera": base_T_camera, "prism": base_T_prism}`` (4×4, metres),
    ``"readout"``: the camera's rolling-shutter readout time (s, a 0-d array; 0 without ``camera_readout_ms``)
    and, with ``camera_lenses``, ``"lenses"``: the camera's two lenses (``camera.DualFisheye``), and
    ``"lens_yaw_sigma"`` (2,) rad when it gives each lens's yaw σ.
    Raises CalibrationError naming the file and the key."""
    data = read_yaml(path, CalibrationError)
    if not isinstance(data, dict):
        raise CalibrationError(f"{path}: expected a mapping with {' and '.join(CALIBRATION_KEYS)}")
    out = {}
    for key, child in CALIBRATION_KEYS.items():
        entry = data.get(key)
        where = f"{path}: {key}"
        if not isinstance(entry, dict):
            raise CalibrationError(f"{where}: missing; expected {{xyz: [x, y, z], rpy_deg: [r, p, y]}}")
        xyz = _vector(entry, "xyz", where)
        rpy = np.radians(_vector(entry, "rpy_deg", where, default=[0.0, 0.0, 0.0]))
        out[child] = make_T(rpy_to_matrix(*rpy), xyz)
    readout = data.get(READOUT_KEY, 0.0)
    if (not isinstance(readout, (int, float)) or isinstance(readout, bool) or not math.isfinite(readout)
            or not 0.0 <= readout < 1000.0):
        raise CalibrationError(f"{path}: {READOUT_KEY}: expected milliseconds in [0, 1000), got {readout!r}")
    out["readout"] = np.array(1e-3 * float(readout))
    if LENSES_KEY in data:
        out["lenses"] = _lenses(data[LENSES_KEY], f"{path}: {LENSES_KEY}")
        if "yaw_sigma_deg" in data[LENSES_KEY]:
            sigma = data[LENSES_KEY]["yaw_sigma_deg"]
            if (not isinstance(sigma, list) or len(sigma) != 2 or not all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x >= 0
                    for x in sigma)):
                raise CalibrationError(f"{path}: {LENSES_KEY}.yaw_sigma_deg: expected [front, back] of non-negative "
                                       f"degrees, got {sigma!r}")
            out["lens_yaw_sigma"] = np.radians(np.array(sigma, dtype=float))
    return out


def _lenses(entry, where: str) -> DualFisheye:
    """The ``camera_lenses`` entry as a ``DualFisheye`` (CalibrationError naming ``where`` and the key)."""
    if not isinstance(entry, dict):
        raise CalibrationError(f"{where}: expected {{lens_offset_mm: o, back_lens_rotation_deg: [r, p, y], "
                               "stitch_distance_m: d or .inf, blend_band_deg: b}")
    unknown = set(entry) - {"lens_offset_mm", "back_lens_rotation_deg", "stitch_distance_m", "blend_band_deg",
                            "axis_azimuth_deg", "yaw_sigma_deg"}
    if unknown:
        raise CalibrationError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
    values = {}
    for key, default in (("lens_offset_mm", 0.0), ("stitch_distance_m", math.inf), ("blend_band_deg", 2.0),
                         ("axis_azimuth_deg", 0.0)):
        v = entry.get(key, default)
        if not isinstance(v, (int, float)) or isinstance(v, bool) or math.isnan(v):
            raise CalibrationError(f"{where}.{key}: expected a number, got {v!r}")
        values[key] = float(v)
    rotation = np.radians(_vector(entry, "back_lens_rotation_deg", where, default=[0.0, 0.0, 0.0]))
    try:
        return DualFisheye(1e-3 * values["lens_offset_mm"], rotation, values["stitch_distance_m"],
                           math.radians(values["blend_band_deg"]), math.radians(values["axis_azimuth_deg"]))
    except ConfigurationError as e:
        raise CalibrationError(f"{where}: {e}") from None
