"""The marker map: surveyed ArUco marker centres, loaded from and saved to YAML (doc/design.md §3).

```yaml
dictionary: DICT_4X4_50
size: 0.19            # black square side, metres
frame_id: map
markers:
  - {id: 3, position: [12.031, 4.210, 1.352]}
  - {id: 7, position: [3.5, -2.0, 1.1], size: 0.30}   # per-marker override
```
Positions in metres in ``frame_id``. Optional per-marker ``sigma`` (survey 1-σ, metres,
default the map's ``survey_sigma``, itself default 0.002 m) and ``normal`` (unit vector out of the
marker's face, from its surveyed corners: ``aruco-abs-orient markers``; a marker is not looked for
from behind); ``covariance_mm2`` (``aruco-abs-orient map``'s, six numbers): a bearing then weighs the marker by
its σ across the sight line (:meth:`Marker.sigma_across`), not by ``sigma``, its worst axis.

National grids: with ``origin: [E, N, H]`` the positions are written as surveyed (full coordinates,
LV95 E ≈ 2 600 000) and the map holds them relative to the origin, as everything in ROS is (float32
consumers such as rviz lose millimetres at 10⁶ m); ``to_dict``/``save`` give full coordinates back.
The MS60 driver's ``~origin`` must be the same. ``grid`` names the national grid (LV95, UTM32N, GK3, EPSG:2056,
…: :func:`north.parse_grid`): with the origin it gives the meridian convergence, grid north against true north.
"""

from __future__ import annotations

import math
from typing import Dict, List, NamedTuple, Optional

import numpy as np

from .errors import InputFileError

__all__ = ["MarkerMapError", "Marker", "MarkerMap", "ARUCO_DICTIONARIES"]

# Names accepted for ``dictionary`` (cv2.aruco predefined dictionaries).
ARUCO_DICTIONARIES = tuple(
    f"DICT_{b}X{b}_{n}" for b in (4, 5, 6, 7) for n in (50, 100, 250, 1000)
) + ("DICT_ARUCO_ORIGINAL", "DICT_APRILTAG_16h5", "DICT_APRILTAG_25h9", "DICT_APRILTAG_36h10",
     "DICT_APRILTAG_36h11")


def upright_rotation(normal) -> np.ndarray:
    """map_R_marker (..., 3, 3) of square face(s) with outward ``normal`` (..., 3) (its z) and y as close to map
    +z as possible (a marker mounted upright); a face looking straight up or down gets y along map +x."""
    z = np.asarray(normal, dtype=float)
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    y = np.array([0.0, 0.0, 1.0]) - z[..., 2:3] * z
    flat = np.linalg.norm(y, axis=-1, keepdims=True) < 1e-9
    y = np.where(flat, np.array([1.0, 0.0, 0.0]) - z[..., 0:1] * z, y)
    y = y / np.linalg.norm(y, axis=-1, keepdims=True)
    return np.stack([np.cross(y, z), y, z], axis=-1)


def square_corners(size: float, normal) -> np.ndarray:
    """The corners (..., 4, 3) of upright square(s) of side ``size`` m and outward ``normal`` (..., 3): offsets
    from the centre in the axes ``normal`` is given in, in cyclic order (c0, c2 and c1, c3 opposite)."""
    half = 0.5 * size * np.array([[-1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, -1.0, 0.0], [-1.0, -1.0, 0.0]])
    return np.einsum("...ij,kj->...ki", upright_rotation(normal), half)


class MarkerMapError(InputFileError):
    """A marker map that cannot be used: the message names the file and the field."""


class Marker(NamedTuple):
    """One surveyed marker: ``id``, centre ``position`` (3,) in metres (relative to the map's origin),
    black-square ``size`` in metres, survey 1-σ ``sigma`` in metres, ``normal`` (3,) unit vector out
    of its face or None (not surveyed), ``covariance`` (3, 3) m² of its position or None (a survey's
    ``sigma`` in every direction)."""

    id: int
    position: np.ndarray
    size: float
    sigma: float
    normal: Optional[np.ndarray] = None
    covariance: Optional[np.ndarray] = None

    def sigma_across(self, point) -> float:
        """1-σ (m) of the position across the line of sight from ``point`` (map, relative to the origin): the
        larger semi-axis of its covariance projected on the plane perpendicular to that line, which is what a
        bearing from there sees (a mapped marker's worst axis is usually along the sight lines it was mapped
        from); ``sigma`` without a covariance or a point (the line undefined)."""
        if self.covariance is None or point is None:
            return self.sigma
        d = self.position - np.asarray(point, dtype=float)
        n = float(np.linalg.norm(d))
        if not n > 0.0:
            return self.sigma
        across = np.eye(3) - np.outer(d, d) / n ** 2
        return math.sqrt(max(float(np.linalg.eigvalsh(across @ self.covariance @ across)[-1]), 0.0))

    def visible_from(self, point, margin: float = 0.0) -> bool:
        """False when ``point`` (map, relative to the origin) is more than ``margin`` m behind the plane
        of the marker's face (its normal known): a marker "seen" from there is a false detection."""
        if self.normal is None:
            return True
        return float(np.dot(np.asarray(point, dtype=float) - self.position, self.normal)) > -margin


class MarkerMap:
    """Markers by id, their ArUco dictionary and frame."""

    def __init__(self, markers: List[Marker], dictionary: str = "DICT_4X4_50", frame_id: str = "map",
                 source: str = "<memory>", origin=None, grid: Optional[str] = None):
        if dictionary not in ARUCO_DICTIONARIES:
            raise MarkerMapError(f"{source}: dictionary: unknown ArUco dictionary {dictionary!r}; "
                                 f"expected one of {', '.join(ARUCO_DICTIONARIES)}")
        self.dictionary = dictionary
        self.frame_id = frame_id
        self.source = source
        self.origin = None if origin is None else np.asarray(origin, dtype=float).reshape(3)
        self.grid = grid
        self.markers: Dict[int, Marker] = {}
        for m in markers:
            if m.id in self.markers:
                raise MarkerMapError(f"{source}: markers: id {m.id} appears twice")
            self.markers[m.id] = m

    def __len__(self) -> int:
        return len(self.markers)

    def __contains__(self, marker_id: int) -> bool:
        return marker_id in self.markers

    def __getitem__(self, marker_id: int) -> Marker:
        return self.markers[marker_id]

    def __iter__(self):
        return iter(self.markers.values())

    @property
    def ids(self) -> List[int]:
        return sorted(self.markers)

    def with_markers(self, markers: List[Marker]) -> MarkerMap:
        """The same map (dictionary, frame, source, origin, grid) with ``markers`` instead of its own."""
        return MarkerMap(markers, self.dictionary, self.frame_id, self.source, self.origin, self.grid)

    @classmethod
    def from_dict(cls, data, source: str = "<memory>") -> MarkerMap:
        """Validate a parsed YAML document; every problem names ``source`` and the field."""
        if not isinstance(data, dict):
            raise MarkerMapError(f"{source}: expected a mapping with 'dictionary', 'size', 'markers'")
        default_size = _positive(data.get("size"), source, "size") if "size" in data else None
        survey_sigma = _positive(data.get("survey_sigma", 0.002), source, "survey_sigma")
        origin = data.get("origin")
        if origin is not None and (not isinstance(origin, (list, tuple)) or len(origin) != 3
                                   or not all(_is_finite_number(x) for x in origin)):
            raise MarkerMapError(f"{source}: origin: expected [E, N, H] in metres, got {origin!r}")
        shift = np.zeros(3) if origin is None else np.array(origin, dtype=float)
        grid = data.get("grid")
        if grid is not None:
            from .north import NorthError, parse_grid

            try:
                parse_grid(grid)
            except NorthError as e:
                raise MarkerMapError(f"{source}: {e}") from None
        items = data.get("markers")
        if not isinstance(items, list) or not items:
            raise MarkerMapError(f"{source}: markers: expected a non-empty list of {{id, position}}")
        markers = []
        for i, item in enumerate(items):
            where = f"markers[{i}]"
            if not isinstance(item, dict):
                raise MarkerMapError(f"{source}: {where}: expected a mapping with 'id' and 'position'")
            mid = item.get("id")
            if isinstance(mid, bool) or not isinstance(mid, int) or mid < 0:
                raise MarkerMapError(f"{source}: {where}.id: expected a non-negative integer, got {mid!r}")
            pos = item.get("position")
            if (not isinstance(pos, (list, tuple)) or len(pos) != 3
                    or not all(_is_finite_number(x) for x in pos)):
                raise MarkerMapError(f"{source}: {where}.position: expected [x, y, z] in metres, got {pos!r}")
            if "size" in item:
                size = _positive(item["size"], source, where + ".size")
            elif default_size is not None:
                size = default_size
            else:
                raise MarkerMapError(f"{source}: {where}.size: no size here and no top-level 'size'")
            sigma = _positive(item.get("sigma", survey_sigma), source, where + ".sigma")
            normal = item.get("normal")
            if normal is not None:
                if (not isinstance(normal, (list, tuple)) or len(normal) != 3
                        or not all(_is_finite_number(x) for x in normal) or not 0.9 < np.linalg.norm(normal) < 1.1):
                    raise MarkerMapError(f"{source}: {where}.normal: expected a unit vector [x, y, z], got {normal!r}")
                normal = np.array(normal, dtype=float) / np.linalg.norm(normal)
            cov = _covariance(item.get("covariance_mm2"), source, where + ".covariance_mm2")
            markers.append(Marker(mid, np.array(pos, dtype=float) - shift, size, sigma, normal, cov))
        return cls(markers, str(data.get("dictionary", "DICT_4X4_50")), str(data.get("frame_id", "map")),
                   source, origin, grid)

    @classmethod
    def load(cls, path: str) -> MarkerMap:
        """Load and validate a marker map YAML file. Raises MarkerMapError."""
        from .tum import read_yaml

        return cls.from_dict(read_yaml(path, MarkerMapError), source=path)

    def to_dict(self) -> dict:
        """The YAML document: positions in full coordinates (origin added back), normals where known."""
        shift = np.zeros(3) if self.origin is None else self.origin
        out = {"dictionary": self.dictionary, "frame_id": self.frame_id}
        if self.origin is not None:
            out["origin"] = [round(float(x), 6) for x in self.origin]
        if self.grid is not None:
            out["grid"] = self.grid
        out["markers"] = []
        for m in self:
            item = {"id": m.id, "position": [round(float(x), 6) for x in m.position + shift], "size": m.size,
                    "sigma": m.sigma}
            if m.normal is not None:
                item["normal"] = [round(float(x), 6) for x in m.normal]
            if m.covariance is not None:
                item["covariance_mm2"] = [round(1e6 * float(m.covariance[i, j]), 6) for i, j in _UPPER]
            out["markers"].append(item)
        return out

    def to_full(self, xyz) -> np.ndarray:
        """Map coordinates (relative to the origin) → full coordinates (E, N, H); (..., 3)."""
        xyz = np.asarray(xyz, dtype=float)
        return xyz if self.origin is None else xyz + self.origin

    def save(self, path: str) -> None:
        """Write the map as YAML, atomically."""
        import yaml

        from .tum import atomic_write_text

        atomic_write_text(path, yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None))

    def positions(self, ids: Optional[List[int]] = None) -> np.ndarray:
        """Marker centres (N, 3) in metres for ``ids`` (default: all, sorted by id)."""
        return np.array([self.markers[i].position for i in (self.ids if ids is None else ids)]).reshape(-1, 3)


#: the (row, column) of each of the six numbers of ``covariance_mm2``: xx, xy, xz, yy, yz, zz
_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _covariance(value, source: str, field: str) -> Optional[np.ndarray]:
    """``covariance_mm2`` (six numbers, mm²) as a symmetric positive-definite 3×3 matrix in m², or None."""
    if value is None:
        return None
    if not isinstance(value, (list, tuple)) or len(value) != 6 or not all(_is_finite_number(x) for x in value):
        raise MarkerMapError(f"{source}: {field}: expected [xx, xy, xz, yy, yz, zz] in mm², got {value!r}")
    cov = np.zeros((3, 3))
    for (i, j), v in zip(_UPPER, value):
        cov[i, j] = cov[j, i] = 1e-6 * float(v)
    if not np.all(np.linalg.eigvalsh(cov) > 0):
        raise MarkerMapError(f"{source}: {field}: not positive definite: expected a covariance, got {value!r}")
    return cov


def _is_finite_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _positive(x, source: str, field: str) -> float:
    if not _is_finite_number(x) or x <= 0:
        raise MarkerMapError(f"{source}: {field}: expected a positive number (metres), got {x!r}")
    return float(x)
