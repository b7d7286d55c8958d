"""TUM trajectory files: one pose per line, ``t x y z qx qy qz qw`` (seconds, metres).

The package's one reader/writer of the format (truth files, offline results, simulator input).
Writing is atomic: the file appears complete or not at all.
"""

from __future__ import annotations

import math
import os
import tempfile
from typing import NamedTuple

import numpy as np

from .transforms import make_T, matrix_to_quat, quat_to_matrix

__all__ = ["TumError", "Trajectory", "read_tum", "write_tum", "atomic_write_text"]


class TumError(ValueError):
    """A TUM file that cannot be read: names the file and the line."""


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

    @classmethod
    def from_transforms(cls, stamps, world_T_frame) -> Trajectory:
        T = np.asarray(world_T_frame, dtype=float)
        return cls(np.asarray(stamps, dtype=float), T[:, :3, 3].copy(), matrix_to_quat(T[:, :3, :3]))


def atomic_write_text(path: str, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same directory and a rename."""
    directory = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def read_tum(path: str) -> Trajectory:
    """Read a TUM file; ``#`` comments and blank lines are skipped. Raises TumError."""
    rows = []
    try:
        with open(path) as f:
            for lineno, line in enumerate(f, 1):
                line = line.strip()
                if not line or line.startswith("#"):
                    continue
                fields = line.replace(",", " ").split()
                if len(fields) != 8:
                    raise TumError(f"{path}:{lineno}: expected 8 fields 't x y z qx qy qz qw', got {len(fields)}")
                try:
                    values = [float(x) for x in fields]
                except ValueError:
                    raise TumError(f"{path}:{lineno}: not a number in {line!r}") from None
                if not all(math.isfinite(x) for x in values):
                    raise TumError(f"{path}:{lineno}: NaN or inf in {line!r}")
                rows.append(values)
    except OSError as e:
        raise TumError(f"{path}: cannot read: {e.strerror}") from None
    data = np.array(rows, dtype=float).reshape(-1, 8)
    return Trajectory(data[:, 0], data[:, 1:4], data[:, 4:8])


def write_tum(path: str, trajectory: Trajectory, header: str = "") -> None:
    """Write a TUM file atomically (stamps with 9 decimals, positions with 6)."""
    lines = [f"# {h}" for h in header.splitlines()] if header else []
    for t, p, q in zip(trajectory.stamps, trajectory.positions, trajectory.quats):
        lines.append(f"{t:.9f} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}")
    atomic_write_text(path, "\n".join(lines) + "\n")
