"""TUM trajectory files: one pose per line, ``t x y z qx qy qz qw`` (seconds, metres).

The package's one reader/writer of the format (truth files, offline results, simulator input),
and its file helpers: atomic writes (the file appears complete or not at all), text and YAML reading
with one-line errors that name the file (a byte-order mark is dropped, UTF-16 decoded, a binary file
or one in an unknown encoding refused: never a UnicodeDecodeError).
"""

from __future__ import annotations

import math
import os
import re
import tempfile
from typing import NamedTuple, Optional, Tuple

import numpy as np

from .errors import InputFileError
from .transforms import make_T, matrix_to_quat, quat_to_matrix

__all__ = ["TumError", "WriteError", "Trajectory", "read_tum", "write_tum", "atomic_write_text", "atomic_write_bytes",
           "slerp", "read_yaml", "read_text", "sorted_series"]


class TumError(InputFileError):
    """A TUM file that cannot be read: names the file and the line."""


class WriteError(InputFileError):
    """A file that cannot be written (its directory cannot be made, no permission, disk full): names the file."""


class Trajectory(NamedTuple):
    """Poses of a frame in a world frame: ``stamps`` (N,) s, ``positions`` (N, 3) m,
    ``quats`` (N, 4) as (x, y, z, w)."""

    stamps: np.ndarray
    positions: np.ndarray
    quats: np.ndarray

    @property
    def rotations(self) -> np.ndarray:
        """Rotation matrices (N, 3, 3) world_R_frame."""
        return quat_to_matrix(self.quats)

    @property
    def transforms(self) -> np.ndarray:
        """Homogeneous transforms (N, 4, 4) world_T_frame."""
        return make_T(self.rotations, self.positions)

    def interpolate(self, t):
        """Poses at time(s) ``t`` (s): linear in position, slerp in rotation.

        Returns ``(positions (..., 3), quats (..., 4), valid (...))``; times outside
        [stamps[0], stamps[-1]] are not extrapolated: they are clamped and flagged invalid.
        The stamps must be increasing.
        """
        t = np.asarray(t, dtype=float)
        n = len(self.stamps)
        if n == 0:
            raise TumError("cannot interpolate an empty trajectory")
        valid = (t >= self.stamps[0]) & (t <= self.stamps[-1])
        if n == 1:
            shape = t.shape
            return (np.broadcast_to(self.positions[0], shape + (3,)).copy(),
                    np.broadcast_to(self.quats[0], shape + (4,)).copy(), valid)
        i = np.clip(np.searchsorted(self.stamps, t, side="right") - 1, 0, n - 2)
        t0, t1 = self.stamps[i], self.stamps[i + 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            a = np.clip(np.where(t1 > t0, (t - t0) / (t1 - t0), 0.0), 0.0, 1.0)
        p = self.positions[i] + a[..., None] * (self.positions[i + 1] - self.positions[i])
        return p, slerp(self.quats[i], self.quats[i + 1], a), valid

    def transforms_at(self, t):
        """Homogeneous transforms (..., 4, 4) world_T_frame at time(s) ``t`` and a validity mask."""
        p, q, valid = self.interpolate(t)
        return make_T(quat_to_matrix(q), p), valid

    @classmethod
    def from_transforms(cls, stamps, world_T_frame) -> Trajectory:
        T = np.asarray(world_T_frame, dtype=float)
        return cls(np.asarray(stamps, dtype=float), T[:, :3, 3].copy(), matrix_to_quat(T[:, :3, :3]))


def slerp(q0, q1, a) -> np.ndarray:
    """Spherical linear interpolation between quaternions (..., 4) ``(x, y, z, w)`` at fraction(s) ``a``."""
    q0 = np.asarray(q0, dtype=float)
    q1 = np.asarray(q1, dtype=float)
    a = np.asarray(a, dtype=float)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)  # the short way round
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_theta = np.sin(theta)
    small = sin_theta < 1e-9
    with np.errstate(invalid="ignore", divide="ignore"):
        w0 = np.where(small, 1.0 - a, np.sin((1.0 - a) * theta) / sin_theta)
        w1 = np.where(small, a, np.sin(a * theta) / sin_theta)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _read_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


# mkstemp makes 0600; a result file is as readable as any other file the user writes. The umask
# is read once, at import (os.umask is process-wide: not to be called from worker threads).
RESULT_FILE_MODE = 0o666 & ~_read_umask()


def atomic_write_text(path: str, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` through a temporary file in the same directory and a rename."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_bytes(path: str, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same directory (created when missing) and a
    rename. Raises WriteError naming ``path`` when it cannot."""
    directory = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(directory, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=directory)
    except OSError as e:
        raise WriteError(f"{path}: cannot write: {e.strerror}") from None
    try:
        os.fchmod(fd, RESULT_FILE_MODE)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException as e:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(e, OSError):  # disk full, a directory in the way
            raise WriteError(f"{path}: cannot write: {e.strerror}") from None
        raise


def read_tum(path: str) -> Trajectory:
    """Read a TUM file (blank- or comma-separated, '.' decimal marks); ``#`` comments and blank lines are
    skipped. Raises TumError naming the file and the line (a decimal comma is refused, never misread)."""
    rows = []
    for lineno, line in enumerate(read_text(path, TumError, "TUM trajectory").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if "," in line and len(line.split()) > 1:
            raise TumError(f"{path}:{lineno}: commas between blank-separated fields (a decimal comma?): expected "
                           f"'t x y z qx qy qz qw' with '.' decimal marks, got {_shown(line)}")
        fields = line.replace(",", " ").split()
        if len(fields) != 8:
            raise TumError(f"{path}:{lineno}: expected 8 fields 't x y z qx qy qz qw', got {len(fields)}")
        try:
            values = [float(x) for x in fields if "_" not in x]
        except ValueError:
            values = []
        if len(values) != 8:
            raise TumError(f"{path}:{lineno}: not a number in {_shown(line)}")
        if not all(math.isfinite(x) for x in values):
            raise TumError(f"{path}:{lineno}: NaN or inf in {_shown(line)}")
        rows.append(values)
    data = np.array(rows, dtype=float).reshape(-1, 8)
    return Trajectory(data[:, 0], data[:, 1:4], data[:, 4:8])


def _shown(text: str, limit: int = 80) -> str:
    """``text`` quoted on one line for an error message, cut to ``limit`` characters."""
    return repr(text if len(text) <= limit else text[:limit] + "…")


def read_text(path: str, error: type, what: str = "text") -> str:
    """The text of ``path``: UTF-8 (a byte-order mark dropped), UTF-16 with its byte-order mark, or Windows-1252
    (Latin-1 spreadsheets). ``error`` (an exception class) with one line naming the file when it cannot be
    read, holds NUL or other control bytes (a binary file) or decodes in none of these; ``what``: the kind of
    file expected, for that message."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        raise error(f"{path}: cannot read: {e.strerror}") from None
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            return data.decode("utf-16")  # the codec drops the byte-order mark
        except UnicodeDecodeError:
            raise error(f"{path}: not a {what} file: a UTF-16 byte-order mark, then bytes that are not UTF-16") \
                from None
    control = re.search(rb"[\x00-\x08\x0b\x0e-\x1f\x7f]", data)
    if control:
        raise error(f"{path}: not a {what} file: control byte 0x{control.group()[0]:02x} at offset "
                    f"{control.start()} (a binary file?)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        try:
            text = data.decode("cp1252")
        except UnicodeDecodeError:
            raise error(f"{path}: not a {what} file: byte 0x{data[e.start]:02x} at offset {e.start} is neither "
                        "UTF-8 nor Windows-1252 text") from None
    return text[1:] if text.startswith("\ufeff") else text


def sorted_series(t, values, name: str, error: type, ncols: Optional[int] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Validated, time-sorted (stable) copies of a stamped series: ``t`` (N,) s and ``values`` (N,) or,
    with ``ncols``, (N, ncols). Raises ``error`` (an exception class) naming ``name`` when the lengths
    differ or a stamp or value is NaN/inf."""
    t = np.asarray(t, dtype=float).ravel()
    v = np.asarray(values, dtype=float)
    if ncols is not None:
        v = v.reshape(-1, ncols) if v.size else v.reshape(0, ncols)
    else:
        v = v.ravel()
    if len(t) != len(v):
        raise error(f"{name}: {len(t)} stamps but {len(v)} values")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
        raise error(f"{name}: NaN or inf in the stamps or values")
    order = np.argsort(t, kind="stable")
    return t[order], v[order]


def read_yaml(path: str, error: type):
    """The parsed YAML document of ``path`` (:func:`read_text`); ``error`` (an exception class) with one line
    naming the file (and the line) when it cannot be read or is not valid YAML."""
    import yaml

    text = read_text(path, error, "YAML")
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f":{mark.line + 1}" if mark is not None else ""
        problem = " ".join(str(getattr(e, "problem", None) or e).split())
        raise error(f"{path}{where}: not valid YAML: {problem}") from None


def write_tum(path: str, trajectory: Trajectory, header: str = "") -> None:
    """Write a TUM file atomically (stamps with 9 decimals, positions with 6)."""
    lines = [f"# {h}" for h in header.splitlines()] if header else []
    for t, p, q in zip(trajectory.stamps, trajectory.positions, trajectory.quats):
        lines.append(f"{t:.9f} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}")
    atomic_write_text(path, "\n".join(lines) + "\n")
