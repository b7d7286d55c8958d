"""Grid north and true north: the meridian convergence of a national grid at a site (doc/design.md §2).

In: the grid the survey is in (a marker map's ``grid:``: ``LV95``, ``LV03``, ``UTM32N`` / ``UTM 33S``,
``GK3`` (DHDN Gauss-Krüger zone 3), or the EPSG code of one of these: 2056, 21781, 326zz, 327zz, 258zz,
31466-31469) and a point of it (E, N in metres: the map's ``origin``). Out: the meridian convergence γ (rad)
there, the bearing of grid north clockwise from true north (navsat_transform's convention), and
:class:`NorthReference`, what the node and ``process`` refer their heading to: ``true = grid − γ`` for a
REP-103 yaw; :meth:`NorthReference.turn_map` and :meth:`NorthReference.turn_point` turn the marker map and the
prism positions by −γ about the origin (the grid's scale kept). γ comes from PROJ's factors where pyproj
imports, else from closed forms (Karney's Krüger series for UTM and Gauss-Krüger, swisstopo's double
projection for LV95 / LV03) that agree with PROJ within 10⁻⁸ rad.
"""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING, Callable, NamedTuple, Optional, Tuple

import numpy as np

from .errors import ConfigurationError

if TYPE_CHECKING:
    from .markers import MarkerMap

__all__ = ["NorthError", "Grid", "parse_grid", "convergence", "convergence_closed_form", "NorthReference",
           "NORTHS"]

NORTHS = ("grid", "true")
"""What a heading can be referred to: the grid's north (the map's y axis) or true (geographic) north."""

# ellipsoids: semi-major axis a (m), flattening f
_WGS84 = (6378137.0, 1.0 / 298.257223563)
_GRS80 = (6378137.0, 1.0 / 298.257222101)
_BESSEL = (6377397.155, 1.0 / 299.1528128)


class NorthError(ConfigurationError):
    """A grid name that is not known, a point outside its grid, or a north that is neither grid nor true."""


class Grid(NamedTuple):
    """A national grid: ``name`` as written, ``epsg`` code, ``kind`` ('tm' or 'swiss'), ellipsoid (a m, f),
    and for 'tm' the central meridian ``lon0`` (rad), scale ``k0``, false easting/northing (m)."""

    name: str
    epsg: int
    kind: str
    ellipsoid: Tuple[float, float]
    lon0: float = 0.0
    k0: float = 1.0
    false_easting: float = 0.0
    false_northing: float = 0.0


def _utm(name: str, zone: int, south: bool, epsg: int, ellipsoid=_WGS84) -> Grid:
    if not 1 <= zone <= 60:
        raise NorthError(f"grid {name!r}: UTM zone {zone} is not in 1-60")
    return Grid(name, epsg, "tm", ellipsoid, math.radians(6.0 * zone - 183.0), 0.9996, 500000.0,
                10000000.0 if south else 0.0)


def _gk(name: str, zone: int, epsg: int) -> Grid:
    if not 2 <= zone <= 5:
        raise NorthError(f"grid {name!r}: DHDN Gauss-Krüger zone {zone} is not in 2-5")
    return Grid(name, epsg, "tm", _BESSEL, math.radians(3.0 * zone), 1.0, zone * 1e6 + 500000.0, 0.0)


_SWISS = {"LV95": (2056, 2600000.0, 1200000.0), "LV03": (21781, 600000.0, 200000.0)}


def parse_grid(text: str) -> Grid:
    """The grid named ``text`` (case and spaces ignored): LV95, LV03, UTM<zone><N|S> (WGS84),
    GK<zone> (DHDN), or ``EPSG:<code>`` of one of them (ETRS89 UTM 258zz too). Raises NorthError."""
    if not isinstance(text, str) or not text.strip():
        raise NorthError(f"grid: expected a grid name (LV95, UTM32N, GK3, EPSG:2056, ...), got {text!r}")
    key = re.sub(r"[\s_/-]", "", text).upper()
    if key in _SWISS:
        return Grid(text, _SWISS[key][0], "swiss", _BESSEL, false_easting=_SWISS[key][1],
                    false_northing=_SWISS[key][2])
    m = re.fullmatch(r"UTM(\d{1,2})([NS])", key)
    if m:
        south = m.group(2) == "S"
        return _utm(text, int(m.group(1)), south, (32700 if south else 32600) + int(m.group(1)))
    m = re.fullmatch(r"GK(\d)", key)
    if m:
        return _gk(text, int(m.group(1)), 31464 + int(m.group(1)))
    m = re.fullmatch(r"EPSG:?(\d+)", key)
    if m:
        code = int(m.group(1))
        for name, (epsg, _, _) in _SWISS.items():
            if code == epsg:
                return parse_grid(name)._replace(name=text)
        if 32601 <= code <= 32660 or 32701 <= code <= 32760:
            return _utm(text, code % 100, code > 32700, code)
        if 25828 <= code <= 25838:
            return _utm(text, code % 100, False, code, _GRS80)
        if 31466 <= code <= 31469:
            return _gk(text, code - 31464, code)
    raise NorthError(f"grid: unknown grid {text!r}; expected LV95, LV03, UTM<zone><N|S>, GK<2-5> or the EPSG code "
                     "of one of them (2056, 21781, 326zz, 327zz, 258zz, 31466-31469)")


# ----------------------------------------------------------------------------------- Transverse Mercator
def _kruger_beta(n: float):
    """Karney (2011), eq. 36: the inverse series' coefficients β1..β6 in the third flattening n."""
    return (n / 2 - 2 * n**2 / 3 + 37 * n**3 / 96 - n**4 / 360 - 81 * n**5 / 512 + 96199 * n**6 / 604800,
            n**2 / 48 + n**3 / 15 - 437 * n**4 / 1440 + 46 * n**5 / 105 - 1118711 * n**6 / 3870720,
            17 * n**3 / 480 - 37 * n**4 / 840 - 209 * n**5 / 4480 + 5569 * n**6 / 90720,
            4397 * n**4 / 161280 - 11 * n**5 / 504 - 830251 * n**6 / 7257600,
            4583 * n**5 / 161280 - 108847 * n**6 / 3991680,
            20648693 * n**6 / 638668800)


def _tm_convergence(grid: Grid, east: float, north: float) -> float:
    """γ (rad) of a Transverse Mercator grid at (E, N): Karney's inverse Krüger series, γ = γ' + γ''."""
    a, f = grid.ellipsoid
    n = f / (2 - f)
    A = a / (1 + n) * (1 + n**2 / 4 + n**4 / 64 + n**6 / 256)
    xi = (north - grid.false_northing) / (grid.k0 * A)
    eta = (east - grid.false_easting) / (grid.k0 * A)
    beta = _kruger_beta(n)
    xi1, eta1, p, q = xi, eta, 1.0, 0.0
    for j, b in enumerate(beta, start=1):
        xi1 -= b * math.sin(2 * j * xi) * math.cosh(2 * j * eta)
        eta1 -= b * math.cos(2 * j * xi) * math.sinh(2 * j * eta)
        p -= 2 * j * b * math.cos(2 * j * xi) * math.cosh(2 * j * eta)
        q += 2 * j * b * math.sin(2 * j * xi) * math.sinh(2 * j * eta)
    return math.atan(math.tan(xi1) * math.tanh(eta1)) + math.atan2(q, p)


# ----------------------------------------------------------------------------------- Swiss oblique Mercator
_CH_LAT0 = math.radians(46 + 57 / 60 + 8.66 / 3600)      # Bern, the projection's centre (Bessel latitude)
_CH_LON0 = math.radians(7 + 26 / 60 + 22.50 / 3600)
_CH_R = 6378815.90365                                     # m, radius of the projection sphere
_CH_ALPHA = 1.00072913843038                              # ellipsoid → sphere longitude ratio
_CH_B0 = math.radians(46 + 54 / 60 + 27.83324844 / 3600)  # the centre's latitude on the sphere
_CH_K = 0.0030667323772751                                # the sphere's latitude constant


def _swiss_forward(lat: float, lon: float) -> Tuple[float, float]:
    """(Y, X) m of the Swiss projection (no false origin) of Bessel (lat, lon) rad; swisstopo's formulas."""
    e = math.sqrt(_BESSEL[1] * (2 - _BESSEL[1]))
    s = (_CH_ALPHA * math.log(math.tan(math.pi / 4 + lat / 2))
         - _CH_ALPHA * e / 2 * math.log((1 + e * math.sin(lat)) / (1 - e * math.sin(lat))) + _CH_K)
    b = 2 * (math.atan(math.exp(s)) - math.pi / 4)
    l = _CH_ALPHA * (lon - _CH_LON0)  # noqa: E741
    l_bar = math.atan(math.sin(l) / (math.sin(_CH_B0) * math.tan(b) + math.cos(_CH_B0) * math.cos(l)))
    b_bar = math.asin(math.cos(_CH_B0) * math.sin(b) - math.sin(_CH_B0) * math.cos(b) * math.cos(l))
    return _CH_R * l_bar, _CH_R / 2 * math.log((1 + math.sin(b_bar)) / (1 - math.sin(b_bar)))


def _swiss_inverse(y: float, x: float) -> Tuple[float, float]:
    """Bessel (lat, lon) rad of the Swiss projection's (Y, X) m (no false origin); swisstopo's formulas."""
    e = math.sqrt(_BESSEL[1] * (2 - _BESSEL[1]))
    l_bar, b_bar = y / _CH_R, 2 * (math.atan(math.exp(x / _CH_R)) - math.pi / 4)
    b = math.asin(math.cos(_CH_B0) * math.sin(b_bar) + math.sin(_CH_B0) * math.cos(b_bar) * math.cos(l_bar))
    l = math.atan(math.sin(l_bar) / (math.cos(_CH_B0) * math.cos(l_bar) - math.sin(_CH_B0) * math.tan(b_bar)))  # noqa: E741
    lon = _CH_LON0 + l / _CH_ALPHA
    lat = b
    for _ in range(20):
        s = ((math.log(math.tan(math.pi / 4 + b / 2)) - _CH_K) / _CH_ALPHA
             + e * math.log(math.tan(math.pi / 4 + math.asin(e * math.sin(lat)) / 2)))
        lat, previous = 2 * math.atan(math.exp(s)) - math.pi / 2, lat
        if abs(lat - previous) < 1e-14:
            break
    return lat, lon


def _swiss_convergence(grid: Grid, east: float, north: float) -> float:
    """γ (rad) of LV95/LV03 at (E, N): minus the grid bearing of the meridian, from the projection's
    derivative along it (central differences over 10⁻⁶ rad: 10⁻¹² rad)."""
    lat, lon = _swiss_inverse(east - grid.false_easting, north - grid.false_northing)
    h = 1e-6
    y1, x1 = _swiss_forward(lat + h, lon)
    y0, x0 = _swiss_forward(lat - h, lon)
    return -math.atan2(y1 - y0, x1 - x0)


def convergence_closed_form(grid: Grid, east: float, north: float) -> float:
    """γ (rad) at grid coordinates (E, N) m without pyproj (see the module docstring)."""
    return (_tm_convergence if grid.kind == "tm" else _swiss_convergence)(grid, float(east), float(north))


def _pyproj_convergence() -> Optional[Callable[[Grid, float, float], float]]:
    try:
        import pyproj
    except ImportError:
        return None

    def gamma(grid: Grid, east: float, north: float) -> float:
        proj = pyproj.Proj(f"EPSG:{grid.epsg}")
        lon, lat = proj(east, north, inverse=True)
        return math.radians(float(proj.get_factors(lon, lat).meridian_convergence))

    return gamma


def convergence(grid: Grid, east: float, north: float) -> Tuple[float, str]:
    """(γ rad, how: 'pyproj <version>' or 'closed form') at grid coordinates (E, N) m. Raises NorthError for a
    point where the grid's formulas do not hold (NaN, beyond 1000 km of the central meridian)."""
    if not (math.isfinite(east) and math.isfinite(north)):
        raise NorthError(f"grid {grid.name}: the point ({east!r}, {north!r}) is not finite")
    if grid.kind == "tm" and abs(east - grid.false_easting) > 1e6:
        raise NorthError(f"grid {grid.name}: easting {east:.0f} m is {abs(east - grid.false_easting) / 1e3:.0f} km "
                         f"from the central meridian (false easting {grid.false_easting:.0f}): not in this grid "
                         "(a wrong zone, or coordinates without the origin?)")
    if grid.kind == "swiss" and math.hypot(east - grid.false_easting, north - grid.false_northing) > 1e6:
        raise NorthError(f"grid {grid.name}: ({east:.0f}, {north:.0f}) is more than 1000 km from Bern: not in "
                         "this grid (LV95 eastings are about 2 600 000, LV03 about 600 000)")
    gamma = _pyproj_convergence()
    if gamma is not None:
        import pyproj

        return gamma(grid, east, north), f"pyproj {pyproj.__version__}"
    return convergence_closed_form(grid, east, north), "closed form"


class NorthReference(NamedTuple):
    """What a heading is referred to: ``north`` 'grid' or 'true'; ``grid`` (None: unknown); ``gamma`` the
    meridian convergence at the origin (rad; NaN without a grid); ``source`` how γ was computed."""

    north: str = "grid"
    grid: Optional[Grid] = None
    gamma: float = float("nan")
    source: str = ""

    @classmethod
    def make(cls, north: str, grid_name: Optional[str], origin, where: str = "") -> NorthReference:
        """The reference for ``north`` ('grid' or 'true') on the grid ``grid_name`` at ``origin`` [E, N, H]
        (the marker map's). True north needs both; grid north takes them to state γ. Raises NorthError
        naming ``where`` (the parameter or file) and what is missing."""
        if north not in NORTHS:
            raise NorthError(f"{where}north: expected 'grid' or 'true', got {north!r}")
        if grid_name is None:
            if north == "true":
                raise NorthError(f"{where}north: true north needs the marker map's 'grid' (LV95, UTM32N, ...) and "
                                 "'origin' [E, N, H]: the convergence depends on where the site is")
            return cls(north)
        grid = parse_grid(grid_name)
        if origin is None:
            raise NorthError(f"{where}grid {grid_name}: needs the map's 'origin' [E, N, H] in that grid, where the "
                             "convergence is taken")
        gamma, source = convergence(grid, float(origin[0]), float(origin[1]))
        return cls(north, grid, gamma, source)

    @property
    def turn(self) -> float:
        """rad about z from the grid frame to the heading's frame: −γ for true north, 0 for grid north."""
        return -self.gamma if self.north == "true" else 0.0

    def turn_map(self, marker_map: MarkerMap) -> MarkerMap:
        """``marker_map`` in the heading's frame: positions (relative to the origin) and face normals turned by
        :attr:`turn` about z (the map itself for grid north)."""
        if self.turn == 0.0:
            return marker_map
        from .transforms import rot_z

        R = rot_z(self.turn)
        markers = [m._replace(position=R @ m.position, normal=None if m.normal is None else R @ m.normal)
                   for m in marker_map]
        return marker_map.with_markers(markers)

    def turn_point(self, p, cov=None):
        """A map point (3,) m relative to the origin, and its covariance (3×3 m² or None), in the heading's frame."""
        from .transforms import rot_z

        R = rot_z(self.turn)
        p = R @ np.asarray(p, dtype=float)
        return p, (None if cov is None else R @ np.asarray(cov, dtype=float) @ R.T)

    def describe(self) -> str:
        """One line: which north, and the convergence when the grid is known."""
        if self.grid is None:
            return "grid north (the marker map's y axis; no 'grid' given, convergence unknown)"
        sign = "+" if self.gamma >= 0 else "-"
        return (f"{self.north} north ({self.grid.name}, meridian convergence at the origin "
                f"{sign}{abs(math.degrees(self.gamma)):.4f}°, {self.source}; true heading = grid heading "
                f"{'-' if self.gamma >= 0 else '+'} {abs(math.degrees(self.gamma)):.4f}°)")
