"""Survey files → points → the marker map: CSV (``id, E, N, H``), Leica GSI-8/16, corner points.

Points are named as in the field book. A marker's centre is a point named by its ArUco id (``7``,
or ``M7``); a marker surveyed reflectorless at its four corners has them as ``7.1`` … ``7.4`` (also
``7_1``, ``M7-1``), numbered in ArUco's order as seen from the front: top-left, top-right,
bottom-right, bottom-left. From the corners come the centre and the face normal (pointing away from
the wall, towards where the marker can be seen from); they must form a square of side ``size`` in a
plane within ``tolerance``, or the marker is rejected and the offending point named.

CSV: ``id, E, N, H`` per row, the delimiter (comma, semicolon, tab, blanks) and the decimal mark (``.``
or ``,``: a Swiss or German spreadsheet's ``3;1,5;2,5;0,3``) detected or given; a row that reads two
ways is refused with its line (:mod:`aruco_abs_orient.table`). Any file: a byte-order mark is dropped, a
binary file or an unknown encoding is an error naming the file (:func:`aruco_abs_orient.tum.read_text`).

GSI (Leica Geo Serial Interface): one block per line, words separated by blanks; GSI-16 lines start
with ``*``. A word is ``WI`` (2 digits) + 4 information characters (the last one the unit of a
distance) + sign + 8 (GSI-8) or 16 (GSI-16) data characters. Known word indices are in
:data:`GSI_WORDS`; any other is an error naming the file, the line and the word.

Runs on the robots' Python 3.8 / numpy 1.17 (core module: no ROS, no OpenCV).
"""

from __future__ import annotations

import math
import re
from typing import Dict, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from .markers import Marker, MarkerMap, MarkerMapError
from .table import read_table
from .tum import read_text

__all__ = ["SurveyError", "SurveyPoint", "GSI_WORDS", "read_points", "read_csv_points", "read_gsi", "gsi_blocks",
           "format_gsi", "marker_from_corners", "marker_map_from_points"]


class SurveyError(MarkerMapError):
    """A survey file or point that cannot be used: names the file, the line or point, what was expected."""


class SurveyPoint(NamedTuple):
    """A surveyed point: ``name`` (point id), ``xyz`` (3,) metres (E, N, H), ``where`` (file:line)."""

    name: str
    xyz: np.ndarray
    where: str


GSI_WORDS: Dict[int, str] = {
    11: "point id", 12: "serial number", 13: "instrument type", 17: "date", 18: "date and time (year, time)",
    19: "date and time (month, day, time)", 21: "horizontal angle", 22: "vertical angle",
    25: "horizontal angle difference", 31: "slope distance", 32: "horizontal distance", 33: "height difference",
    51: "ppm and prism constant", 52: "number and standard deviation of measurements", 53: "standard deviation",
    58: "prism constant", 59: "ppm", 81: "easting", 82: "northing", 83: "height", 84: "station easting",
    85: "station northing", 86: "station height", 87: "reflector height", 88: "instrument height",
    **{wi: "code / information" for wi in range(41, 50)}, **{wi: "remark" for wi in range(71, 80)},
}
# unit digit (the 4th information character) of a distance word → metres per data unit
GSI_UNITS = {"0": 1e-3, "1": 0.3048e-3, "6": 1e-4, "7": 0.3048e-4, "8": 1e-5}
CORNER_NAME = re.compile(r"^[A-Za-z]*(\d+)[._-]([1-4])$")
CENTRE_NAME = re.compile(r"^[A-Za-z]*(\d+)$")


def gsi_blocks(path: str) -> List[Tuple[int, Dict[int, str], Dict[int, str]]]:
    """``(line number, {WI: data text}, {WI: information text})`` of each block of a GSI-8/16 file."""
    out = []
    for lineno, line in enumerate(read_text(path, SurveyError, "GSI").splitlines(), 1):
        text = line.strip()
        if not text:
            continue
        width = 16 if text.startswith("*") else 8
        data: Dict[int, str] = {}
        info: Dict[int, str] = {}
        for word in text.lstrip("*").split():
            if len(word) != 7 + width or not word[:2].isdigit() or word[6] not in "+-":
                raise SurveyError(f"{path}:{lineno}: word {word!r}: expected a GSI-{width} word (2-digit index, 4 "
                                  f"information characters, sign, {width} data characters)")
            wi = int(word[:2])
            if wi not in GSI_WORDS:
                raise SurveyError(f"{path}:{lineno}: word {word!r}: unknown word index {wi:02d} (expected one of "
                                  f"{', '.join(f'{k:02d}' for k in sorted(GSI_WORDS))})")
            if wi in data:
                raise SurveyError(f"{path}:{lineno}: word index {wi:02d} ({GSI_WORDS[wi]}) appears twice in the block")
            data[wi] = word[6] + word[7:]
            info[wi] = word[2:6]
        out.append((lineno, data, info))
    return out


def gsi_number(path: str, lineno: int, wi: int, data: Dict[int, str], info: Dict[int, str]) -> float:
    """The value of distance word ``wi`` in metres (or, for a remark/code word, the number written in it)."""
    text = data[wi]
    where = f"{path}:{lineno}: word {wi:02d} ({GSI_WORDS[wi]})"
    if wi in range(41, 50) or wi in range(71, 80):
        try:
            return float(text[0] + text[1:].lstrip("0") if text[1:].strip("0") else "0")
        except ValueError:
            raise SurveyError(f"{where}: expected a number, got {text[1:]!r}") from None
    unit = info[wi][3]
    if unit not in GSI_UNITS:
        raise SurveyError(f"{where}: unit digit {unit!r}: expected a distance unit "
                          f"({', '.join(sorted(GSI_UNITS))}: 0 mm, 1 ft/1000, 6 mm/10, 7 ft/10000, 8 mm/100)")
    if not text[1:].isdigit():
        raise SurveyError(f"{where}: expected digits, got {text[1:]!r}")
    return (-1.0 if text[0] == "-" else 1.0) * int(text[1:]) * GSI_UNITS[unit]


def read_gsi(path: str) -> List[SurveyPoint]:
    """The points (WI 11 with 81, 82, 83) of a GSI-8/16 file; blocks without coordinates (raw angle/distance
    measurements) are skipped."""
    points = []
    for lineno, data, info in gsi_blocks(path):
        if not all(wi in data for wi in (81, 82, 83)):
            continue
        if 11 not in data:
            raise SurveyError(f"{path}:{lineno}: coordinates without a point id (word 11)")
        name = data[11][1:].lstrip("0") or "0"
        xyz = np.array([gsi_number(path, lineno, wi, data, info) for wi in (81, 82, 83)])
        points.append(SurveyPoint(name, xyz, f"{path}:{lineno}"))
    return _unique(points, path)


def format_gsi(points: Sequence[Tuple[str, Sequence[float]]], gsi16: bool = True, unit: str = "0",
               extra: Optional[Sequence[Dict[int, str]]] = None) -> str:
    """GSI-8 or GSI-16 text of ``(name, (E, N, H))`` points in ``unit`` (a :data:`GSI_UNITS` digit);
    ``extra``: per point, more words (WI → data text), e.g. a remark word with the time."""
    width = 16 if gsi16 else 8
    scale = GSI_UNITS[unit]
    lines = []
    for k, (name, xyz) in enumerate(points):
        words = [f"11{(k + 1) % 10000:04d}+{str(name).rjust(width, '0')[-width:]}"]
        for wi, v in zip((81, 82, 83), xyz):
            n = int(round(float(v) / scale))
            words.append(f"{wi}..0{unit}{'+' if n >= 0 else '-'}{str(abs(n)).rjust(width, '0')[-width:]}")
        for wi, text in sorted((extra[k] if extra else {}).items()):
            words.append(f"{wi}....{'-' if text.startswith('-') else '+'}{text.lstrip('+-').rjust(width, '0')}")
        lines.append(("*" if gsi16 else "") + " ".join(words))
    return "\n".join(lines) + "\n"


def read_csv_points(path: str, delimiter: Optional[str] = None, decimal: Optional[str] = None) -> List[SurveyPoint]:
    """Points of a CSV ``id, E, N, H`` (a header line and ``#`` comments allowed); ``delimiter`` (``,`` ``;``
    ``tab`` ``blank``) and ``decimal`` (``.`` ``,``) as given, else detected (:func:`table.read_table`)."""
    table = read_table(path, read_text(path, SurveyError, "survey"), (1, 2, 3), 4, SurveyError, "'id, E, N, H'",
                       delimiter, decimal)
    points = []
    for lineno, (name, *xyz) in table.rows:
        if not np.all(np.isfinite(xyz)):
            raise SurveyError(f"{path}:{lineno}: NaN or inf in E, N, H")
        points.append(SurveyPoint(name, np.array(xyz, dtype=float), f"{path}:{lineno}"))
    return _unique(points, path)


def read_points(path: str, delimiter: Optional[str] = None, decimal: Optional[str] = None) -> List[SurveyPoint]:
    """The points of a survey file: GSI when its first block looks like GSI (``*11…`` or ``11…+``), else CSV
    (``delimiter``, ``decimal``: :func:`read_csv_points`'s)."""
    first = next((line.strip() for line in read_text(path, SurveyError, "survey").splitlines() if line.strip()), "")
    if re.match(r"^\*?\d{6}[+-]", first):
        return read_gsi(path)
    return read_csv_points(path, delimiter, decimal)


def _unique(points: List[SurveyPoint], path: str) -> List[SurveyPoint]:
    seen: Dict[str, SurveyPoint] = {}
    for p in points:
        if p.name in seen:
            raise SurveyError(f"{p.where}: point id {p.name!r} already at {seen[p.name].where}: expected each point "
                              "once (remove or rename one)")
        seen[p.name] = p
    return points


def marker_from_corners(marker_id: int, corners: Sequence[SurveyPoint], size: float, tolerance: float,
                        sigma: float) -> Marker:
    """A marker from its four corner points (ArUco order, seen from the front): centre = their mean, normal =
    the plane's, towards the front. Raises SurveyError naming the corner farthest from the square of side
    ``size`` that fits them best when it is more than ``tolerance`` m off (out of plane or in plane)."""
    c = np.array([p.xyz for p in corners], dtype=float)
    centre = c.mean(axis=0)
    d = c - centre
    normal = np.linalg.svd(d)[2][2]
    front = np.cross(c[2] - c[1], c[1] - c[0])  # down × right: towards the viewer
    if float(np.dot(normal, front)) < 0:
        normal = -normal
    right = (c[1] + c[2] - c[0] - c[3]) / 2.0
    right -= normal * float(np.dot(right, normal))
    if np.linalg.norm(right) < 1e-9:
        raise SurveyError(f"marker {marker_id}: corners {', '.join(p.name for p in corners)} do not span a square")
    right /= np.linalg.norm(right)
    up = np.cross(normal, right)
    template = 0.5 * size * np.array([[-1.0, 1.0], [1.0, 1.0], [1.0, -1.0], [-1.0, -1.0]])
    uv = np.stack([d @ right, d @ up], axis=1)
    angle = math.atan2(float(np.sum(template[:, 0] * uv[:, 1] - template[:, 1] * uv[:, 0])),
                       float(np.sum(template * uv)))
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    ideal = centre + (template @ rot.T) @ np.stack([right, up])
    residual = np.linalg.norm(c - ideal, axis=1)
    worst = int(np.argmax(residual))
    if residual[worst] > tolerance:
        off_plane = float(np.dot(d[worst], normal))
        side = float(np.mean(np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1)))
        raise SurveyError(f"{corners[worst].where}: point {corners[worst].name}: {1e3 * residual[worst]:.1f} mm "
                          f"from the {1e3 * size:.0f} mm square fitted to marker {marker_id}'s corners "
                          f"({1e3 * off_plane:.1f} mm out of their plane; mean side {1e3 * side:.1f} mm); "
                          f"expected within {1e3 * tolerance:.1f} mm: re-measure it, or check --size")
    return Marker(marker_id, centre, float(size), float(sigma), normal)


def marker_map_from_points(points: Sequence[SurveyPoint], dictionary: str, size: float, tolerance: float = 0.01,
                           sigma: float = 0.002, origin: Optional[Sequence[float]] = None,
                           source: str = "<survey>") -> MarkerMap:
    """The marker map of surveyed points: centres named by the marker id, or four corners ``id.1`` … ``id.4``;
    other point names are an error naming them (a marker given both ways too)."""
    centres: Dict[int, SurveyPoint] = {}
    corners: Dict[int, Dict[int, SurveyPoint]] = {}
    for p in points:
        m = CORNER_NAME.match(p.name)
        if m:
            corners.setdefault(int(m.group(1)), {})[int(m.group(2))] = p
            continue
        m = CENTRE_NAME.match(p.name)
        if not m:
            raise SurveyError(f"{p.where}: point id {p.name!r}: expected a marker id (7, M7) or a corner (7.1 … 7.4)")
        centres[int(m.group(1))] = p
    markers = []
    for mid, p in centres.items():
        if mid in corners:
            raise SurveyError(f"{p.where}: marker {mid} has a centre point and corner points "
                              f"({', '.join(c.name for c in corners[mid].values())}): expected one or the other")
        markers.append(Marker(mid, np.asarray(p.xyz, dtype=float), float(size), float(sigma)))
    for mid, cs in corners.items():
        missing = [k for k in (1, 2, 3, 4) if k not in cs]
        if missing:
            where = next(iter(cs.values())).where
            raise SurveyError(f"{where}: marker {mid}: corner(s) {', '.join(f'{mid}.{k}' for k in missing)} missing: "
                              "expected the four corners 1-4 (top-left, top-right, bottom-right, bottom-left)")
        markers.append(marker_from_corners(mid, [cs[k] for k in (1, 2, 3, 4)], size, tolerance, sigma))
    if not markers:
        raise SurveyError(f"{source}: no marker points")
    shift = np.zeros(3) if origin is None else np.asarray(origin, dtype=float)
    markers = sorted((m._replace(position=m.position - shift) for m in markers), key=lambda m: m.id)
    return MarkerMap(markers, dictionary, source=source, origin=origin)
