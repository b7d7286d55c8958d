"""Does the marker map fit the recording? The marker bearings, the prism track and the odometry against it.

In: :class:`Sightings` (per marker seen: total-station time, id, unit bearing in the camera frame, the
odometry's rotation of base_link then), the prism track (stamps, positions in map), the mounting
(``base_T_camera``, the prism in base_link) and the map's marker positions ({id: xyz}, m, relative to its
origin). Out: a :class:`MapVerdict`: ``fits``, ``does_not_fit`` or ``undetermined``, one line that says
which markers, how far off and what it looks like (a shift, a rotation, a scale, a wrong origin, another
site's map, one moved marker), and its figures (JSON-able). How it decides: doc/design.md §12. ROS-free
(process, calibrate and the node call it); radians, metres, seconds inside; degrees and metres in messages.
"""

from __future__ import annotations

import collections
import math
import threading
from dataclasses import dataclass, field
from typing import Deque, Dict, List, Mapping, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from .paramspec import Params, param
from .transforms import wrap_angle
from .yawfit import hat_basis, robust_lsq

__all__ = ["MapCheckParams", "Sightings", "SightingSample", "MapVerdict", "check_map", "RollingMapCheck", "FITS",
           "DOES_NOT_FIT", "UNDETERMINED"]

FITS, DOES_NOT_FIT, UNDETERMINED = "fits", "does_not_fit", "undetermined"


@dataclass(frozen=True)
class MapCheckParams(Params):
    """Thresholds of the map check (cfg/params.yaml's ``mapcheck`` section)."""

    fit_deg: float = param(1.0, "the map fits when the median sighting points within this of its marker", "deg",
                           above=0.0)
    knot_spacing: float = param(10.0, "spacing of the hat functions of the map→odom yaw (the odometry's drift)",
                                "s", above=0.0)
    max_time_error: float = param(1.0, "the time-offset errors tried span ± this", "s", 0.0)
    time_step: float = param(0.05, "... in steps of this", "s", above=0.0)
    min_sightings: int = param(30, "fewer sightings give no verdict", "", 1)
    min_travel: float = param(1.0, "prism track needed when only one marker was seen (from one place a single "
                              "bearing fits any map)", "m", 0.0)
    tolerance: float = param(0.3, "a marker placed within this (+ 3 σ) of where a change of the map puts it agrees",
                             "m", 0.0)
    min_ray_spread_deg: float = param(5.0, "a marker is placed when its rays span at least this angle", "deg", 0.0)
    max_sightings: int = param(3000, "more are thinned evenly in time (the check's cost)", "", 1)
    live_max_sightings: int = param(1000, "the node's window of sightings (0.1–0.2 s of CPU a check)", "", 1)
    max_prism_gap: float = param(0.5, "a sighting between two prism positions further apart is not used (as the "
                                 "pipeline's prism_max_gap)", "s", 0.0)
    max_marker_distance: float = param(200.0, "map markers seen farther than this from the prism track (a 19 cm "
                                       "marker is a pixel there) mean a wrong origin or unit", "m", above=0.0)
    max_odom_tilt_deg: float = param(5.0, "the odometry's frame may be tilted up to this (a VO without gravity keeps "
                                     "the platform's starting roll and pitch); a larger estimate is not applied",
                                     "deg", 0.0)


class Sightings(NamedTuple):
    """Markers seen: ``time`` (N,) s on the total-station clock, ``id`` (N,), ``bearing`` (N, 3) unit vectors in
    the camera frame, ``odom_R`` (N, 3, 3) the rotation of base_link in odom at that time."""

    time: np.ndarray
    id: np.ndarray
    bearing: np.ndarray
    odom_R: np.ndarray

    @classmethod
    def from_rows(cls, rows: Sequence[Tuple[float, int, Sequence[float], np.ndarray]]) -> Sightings:
        """From ``(time, id, bearing (3,), odom_R (3, 3))`` rows."""
        if not rows:
            return cls(np.zeros(0), np.zeros(0, dtype=int), np.zeros((0, 3)), np.zeros((0, 3, 3)))
        t, ids, u, R = zip(*rows)
        return cls(np.array(t, dtype=float), np.array(ids, dtype=int), np.array(u, dtype=float).reshape(-1, 3),
                   np.array(R, dtype=float).reshape(-1, 3, 3))


class SightingSample:
    """Sightings of a whole run in bounded memory: every ``stride``-th one kept, the stride doubled (and every
    other one kept dropped) whenever ``2 · size`` are held, so what is kept spans the run evenly (an hour at 30 fps
    holds ``size`` to ``2 · size`` rows, not half a million)."""

    def __init__(self, size: int = MapCheckParams.max_sightings):
        self.size, self.stride, self._seen = int(size), 1, 0
        self._rows: List[tuple] = []

    def add(self, t: float, marker_id: int, bearing, odom_R) -> None:
        if self._seen % self.stride == 0:
            self._rows.append((float(t), int(marker_id), np.asarray(bearing, dtype=float), np.asarray(odom_R)))
            if len(self._rows) >= 2 * self.size:
                self._rows, self.stride = self._rows[::2], 2 * self.stride
        self._seen += 1

    def sightings(self) -> Sightings:
        return Sightings.from_rows(self._rows)


@dataclass
class MapVerdict:
    """``status`` (:data:`FITS`, :data:`DOES_NOT_FIT`, :data:`UNDETERMINED`), ``message`` (one line), ``details``
    (JSON-able figures: median residual, time-offset error tried, markers placed, the change of the map)."""

    status: str
    message: str
    details: Dict[str, object] = field(default_factory=dict)

    def as_dict(self) -> Dict[str, object]:
        return {"status": self.status, "message": self.message, **self.details}


# ------------------------------------------------------------------------------------------------ geometry
def _rotate_z(v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Vectors (N, 3) rotated about z by angles (N,)."""
    c, s = np.cos(a), np.sin(a)
    return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]], axis=1)


def _azimuth(v: np.ndarray) -> np.ndarray:
    return np.arctan2(v[:, 1], v[:, 0])


def _elevation(v: np.ndarray) -> np.ndarray:
    return np.arctan2(v[:, 2], np.hypot(v[:, 0], v[:, 1]))


class _Rays(NamedTuple):
    """Per sighting: the bearing in odom's axes ``b`` (before the map→odom yaw), the camera's lever arm from
    the prism in odom's axes ``lever``, the time ``t`` and the marker ``id``."""

    t: np.ndarray
    id: np.ndarray
    b: np.ndarray
    lever: np.ndarray


def _rays(s: Sightings, base_T_camera, prism_in_base) -> _Rays:
    T = np.asarray(base_T_camera, dtype=float)
    u = s.bearing / np.linalg.norm(s.bearing, axis=1, keepdims=True)
    b = np.einsum("nij,nj->ni", s.odom_R, u @ T[:3, :3].T)
    lever = s.odom_R @ (T[:3, 3] - np.asarray(prism_in_base, dtype=float))
    return _Rays(s.time, s.id, b, lever)


def _tilt_R(w) -> np.ndarray:
    """The rotation by the small angles ``w`` = (about x, about y) (rad): odom's tilt against the level."""
    a, b = float(w[0]), float(w[1])
    ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
    return np.array([[cb, sa * sb, ca * sb], [0.0, ca, -sa], [-sb, sa * cb, ca * cb]])


def _levelled(rays: _Rays, w) -> _Rays:
    """``rays`` with odom's axes levelled by the tilt ``w`` (:func:`_tilt_R`)."""
    R = _tilt_R(w)
    return _Rays(rays.t, rays.id, rays.b @ R.T, rays.lever @ R.T)


def _odom_tilt(rays: _Rays, P: np.ndarray, M: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """The small tilt (about x, about y; rad) of odom's axes that best turns each sighting (map→odom yaw
    ``delta``) onto the direction from the camera to ``M``: least squares of the linearised misses, robust
    (sightings more than 3 × the median miss off count less)."""
    v = M - (P + _rotate_z(rays.lever, delta))
    r = _rotate_z(v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12), -delta) - rays.b
    b = rays.b
    # w × b for w = (wx, wy, 0): (wy bz, -wx bz, wx by - wy bx)
    A = np.stack([np.stack([np.zeros(len(b)), -b[:, 2], b[:, 1]], axis=1),
                  np.stack([b[:, 2], np.zeros(len(b)), -b[:, 0]], axis=1)], axis=2)
    size = np.linalg.norm(r, axis=1)
    w = np.sqrt(1.0 / np.maximum(1.0, size / (3.0 * max(float(np.median(size)), 1e-6))))
    return np.linalg.lstsq((A * w[:, None, None]).reshape(-1, 2), (r * w[:, None]).ravel(), rcond=None)[0]


def _prism_at(track, t: np.ndarray) -> np.ndarray:
    pt, pp = track
    return np.stack([np.interp(t, pt, pp[:, k]) for k in range(3)], axis=1)


def _yaw_track(t: np.ndarray, y: np.ndarray, w: np.ndarray, spacing: float) -> np.ndarray:
    """The map→odom yaw at each sighting: ``y`` (rad, wrapped) fitted robustly by hat functions in time."""
    centre = float(np.angle(np.sum(w * np.exp(1j * y))))
    z = wrap_angle(y - centre)
    A = hat_basis(t, spacing)
    x, _ = robust_lsq(A, z, w)
    return centre + A @ x


def _angles_off(rays: _Rays, P: np.ndarray, M: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """The angle (rad) between each sighting's direction (map→odom yaw ``delta``) and the direction from the
    camera to ``M`` (N, 3)."""
    d = _rotate_z(rays.b, delta)
    v = M - (P + _rotate_z(rays.lever, delta))
    cos = np.einsum("ni,ni->n", d, v) / np.maximum(np.linalg.norm(d, axis=1) * np.linalg.norm(v, axis=1), 1e-12)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def _fit_yaw(rays: _Rays, P: np.ndarray, M: np.ndarray, spacing: float) -> Tuple[np.ndarray, np.ndarray]:
    """(map→odom yaw (N,), angle off (N,)) of sightings aimed at ``M`` from the prism positions ``P``."""
    w = np.cos(_elevation(rays.b)) ** 2 + 1e-3
    delta = np.zeros(len(P))
    for _ in range(3):  # the lever arm turns with the yaw: again with the estimate (≈ lever/range per turn)
        c = P + _rotate_z(rays.lever, delta)
        delta = _yaw_track(rays.t, wrap_angle(_azimuth(M - c) - _azimuth(rays.b)), w, spacing)
    return delta, _angles_off(rays, P, M, delta)


# ------------------------------------------------------------------------------------------- (1) as it is
def _as_is(rays: _Rays, track, M: np.ndarray, p: MapCheckParams) -> Tuple[float, float, np.ndarray]:
    """(median angle off (rad), the time-offset error it is smallest at (s), angles off (N,)) of the map as it
    is: the prism looked up ε s later, ε searched within ±``max_time_error`` (4 × ``time_step`` apart, then
    ``time_step`` around the best)."""
    best = (math.inf, 0.0, np.zeros(0))

    def tried(eps: float) -> None:
        nonlocal best
        P = _prism_at(track, rays.t + eps)
        delta, off = _fit_yaw(rays, P, M, p.knot_spacing)
        tilt = _odom_tilt(rays, P, M, delta)
        if np.max(np.abs(tilt)) <= math.radians(p.max_odom_tilt_deg):  # the levelled fit, where it fits better
            off = min(off, _fit_yaw(_levelled(rays, tilt), P, M, p.knot_spacing)[1], key=np.median)
        med = float(np.median(off))
        if med < best[0] - 1e-9:
            best = (med, float(eps), off)

    coarse = 4.0 * p.time_step
    n = int(math.ceil(p.max_time_error / coarse))
    for eps in sorted(np.clip(np.arange(-n, n + 1) * coarse, -p.max_time_error, p.max_time_error), key=abs):
        tried(eps)  # ties: the smallest error
    centre = best[1]
    for k in (-3, -2, -1, 1, 2, 3):
        if abs(centre + k * p.time_step) <= p.max_time_error:
            tried(centre + k * p.time_step)
    return best


# ------------------------------------------------------------------------------------------- (2) placed
class _Placed(NamedTuple):
    ids: List[int]
    xyz: np.ndarray        # (J, 3) where the markers are seen, map frame
    sigma: np.ndarray      # (J,) m, 1-σ of each (from its rays' scatter)
    rays: np.ndarray       # (J,) sightings used
    misfit: float = math.inf  # rad, median angle between the sightings and their placed markers


def _triangulate(rays: _Rays, P: np.ndarray, delta: np.ndarray, min_spread: float) -> Dict[int, np.ndarray]:
    """{id: xyz} of the markers whose rays (map→odom yaw ``delta``) span at least ``min_spread`` (rad): the point
    nearest to all of them (least squares of the perpendicular misses)."""
    d = _rotate_z(rays.b, delta)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = P + _rotate_z(rays.lever, delta)
    out = {}
    for mid in np.unique(rays.id):
        k = rays.id == mid
        if k.sum() < 3:
            continue
        Q = np.eye(3)[None] - d[k, :, None] * d[k, None, :]        # projections off each ray
        A = Q.sum(axis=0)
        if np.linalg.eigvalsh(A / k.sum())[0] < math.sin(min_spread) ** 2 / 2:
            continue  # the rays hardly cross: no position along them
        out[int(mid)] = np.linalg.solve(A, np.einsum("nij,nj->i", Q, c[k]))
    return out


def _misses(rays: _Rays, P: np.ndarray, hats: np.ndarray, where: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(N, 3): each sighting's direction × the unit direction from the camera to its marker (sin of the angle
    between them), for the map→odom yaw knots, odom's tilt (two) and the marker positions in ``x`` (``where``:
    each sighting's marker index)."""
    k = hats.shape[1]
    delta = hats @ x[:k]
    rays = _levelled(rays, x[k:k + 2])
    v = x[k + 2:].reshape(-1, 3)[where] - (P + _rotate_z(rays.lever, delta))
    return np.cross(_rotate_z(rays.b, delta), v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9))


def _place(rays: _Rays, track, p: MapCheckParams) -> _Placed:
    """Where the markers are seen: the best constant map→odom yaw of a 10° grid (each marker triangulated),
    then the yaw (hat functions) and the positions together by robust Gauss-Newton."""
    P = _prism_at(track, rays.t)
    spread = math.radians(p.min_ray_spread_deg)

    def grid_cost(a: float) -> float:
        placed = _triangulate(rays, P, np.full(len(P), a), spread)
        ok = np.isin(rays.id, list(placed))
        if not ok.any():
            return math.inf
        M = np.array([placed[int(i)] for i in rays.id[ok]])
        off = _angles_off(_Rays(*(v[ok] for v in rays)), P[ok], M, np.full(int(ok.sum()), a))
        return float(np.mean(np.minimum(off, math.radians(5.0)) ** 2)) / max(float(ok.mean()), 1e-3) ** 2

    start = math.radians(10.0) * int(np.argmin([grid_cost(a) for a in np.radians(np.arange(0.0, 360.0, 10.0))]))
    placed = _triangulate(rays, P, np.full(len(P), start), spread)
    ids = sorted(placed)
    if not ids:
        return _Placed([], np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    ok = np.isin(rays.id, ids)
    sub, P = _Rays(*(v[ok] for v in rays)), P[ok]
    where = np.searchsorted(ids, sub.id)
    hats = hat_basis(sub.t, p.knot_spacing)
    k = hats.shape[1]
    x = np.concatenate([np.full(k, start), np.zeros(2), np.concatenate([placed[i] for i in ids])])
    steps = np.concatenate([np.full(k + 2, 1e-6), np.full(3 * len(ids), 1e-5)])
    w = np.ones(len(P))
    cov = np.eye(len(x))
    for _ in range(8):
        r = _misses(sub, P, hats, where, x)
        J = np.stack([(_misses(sub, P, hats, where, x + h * e) - r).ravel() / h
                      for h, e in zip(steps, np.eye(len(x)))], axis=1)
        size = np.linalg.norm(r, axis=1)
        scale = max(1.4826 * float(np.median(size)), math.radians(0.02))
        w = 1.0 / np.maximum(1.0, size / (2.0 * scale))      # Huber-like: outliers (false ids) count less
        sw = np.repeat(np.sqrt(w), 3)
        dx = np.linalg.lstsq(J * sw[:, None], -r.ravel() * sw, rcond=None)[0]
        x = x + dx
        N = J.T @ (J * (sw ** 2)[:, None])
        cov = np.linalg.pinv(N) * float(np.sum(w * size ** 2) / max(2 * len(P) - len(x), 1))
        if np.max(np.abs(x[k:k + 2])) > math.radians(p.max_odom_tilt_deg):
            x[k:k + 2] = 0.0  # not a tilt the odometry can have: the positions without it
        if np.max(np.abs(dx[k + 2:])) < 1e-4 and np.max(np.abs(dx[:k + 2])) < 1e-7:
            break
    xyz = x[k + 2:].reshape(-1, 3)
    j0 = k + 2
    sigma = np.array([math.sqrt(max(float(np.trace(cov[j0 + 3 * j:j0 + 3 * j + 3, j0 + 3 * j:j0 + 3 * j + 3])), 0.0))
                      for j in range(len(ids))])
    misfit = float(np.median(np.arcsin(np.clip(np.linalg.norm(_misses(sub, P, hats, where, x), axis=1), 0, 1))))
    return _Placed(ids, xyz, sigma, np.bincount(where, minlength=len(ids)), misfit)


# ------------------------------------------------------------------------------------- naming the change
class _Change(NamedTuple):
    """map ≈ scale · Rz(rotation) · seen + shift (map coordinates, relative to its origin)."""

    model: str            # shift, rotation, similarity
    scale: float
    rotation: float       # rad
    shift: np.ndarray     # (3,) m
    misses: np.ndarray    # (J,) m, each marker's distance (in the seen frame) after the change


def _fit_change(M: np.ndarray, X: np.ndarray, model: str) -> _Change:
    """The change of kind ``model`` that best takes the seen positions ``X`` to the map's ``M`` (least squares
    in the horizontal plane with complex numbers; heights shifted, and scaled in a similarity)."""
    m, x = M[:, 0] + 1j * M[:, 1], X[:, 0] + 1j * X[:, 1]
    mc, xc = m - m.mean(), x - x.mean()
    a = 1.0 + 0j
    if model != "shift" and np.sum(np.abs(xc) ** 2) > 1e-12:
        a = complex(np.sum(np.conj(xc) * mc) / np.sum(np.abs(xc) ** 2))
        if model == "rotation":
            a /= abs(a)
    s = abs(a)
    t = m.mean() - a * x.mean()
    tz = float(np.mean(M[:, 2] - s * X[:, 2]))
    back_xy = (m - t) / a
    back = np.stack([back_xy.real, back_xy.imag, (M[:, 2] - tz) / s], axis=1)
    return _Change(model, s, float(np.angle(a)), np.array([t.real, t.imag, tz]), np.linalg.norm(back - X, axis=1))


def _describe(change: _Change, origin: Optional[Sequence[float]], tolerance: float) -> str:
    """What a change looks like, in the words of a surveyor."""
    parts = []
    if change.model == "similarity" and abs(math.log(change.scale)) > 0.005:
        s = change.scale
        why = (" (millimetres written as metres?)" if 500 < s < 2000 else " (metres written as millimetres?)"
               if 5e-4 < s < 2e-3 else " (feet?)" if 0.29 < s < 0.31 or 3.2 < s < 3.4 else "")
        parts.append(f"scaled by {s:.4g}{why}")
    deg = math.degrees(change.rotation)
    if change.model != "shift" and abs(deg) > 0.5:
        why = " (E and N exchanged, or the station oriented otherwise)" if min(
            abs(abs(deg) - 90.0), abs(abs(deg) - 180.0)) < 3.0 else ""
        parts.append(f"rotated by {deg:+.1f}° about z around its origin{why}")
    norm = float(np.linalg.norm(change.shift))
    if norm >= 1000.0:
        parts.append(f"{norm / 1000.0:.1f} km off: {_wrong_origin(origin)}")
    elif norm > tolerance * change.scale:
        parts.append("shifted by (" + ", ".join(f"{v:+.2f}" for v in change.shift) + ") m")
    return " and ".join(parts) or "as it is"


def _wrong_origin(origin: Optional[Sequence[float]]) -> str:
    mine = "none" if origin is None else "(" + ", ".join(f"{v:.0f}" for v in origin) + ")"
    return f"a wrong origin (the map's, {mine}, and the MS60 driver's ~origin must be the same)"


def _name_it(placed: _Placed, map_xyz: Mapping[int, Sequence[float]], p: MapCheckParams,
             origin: Optional[Sequence[float]]) -> Tuple[Optional[str], Dict[str, object]]:
    """The sentence that says how the map is off ('' when no marker is placed; None when most placed markers
    are where the map has them, and the figures say which are not), and its figures."""
    M = np.array([map_xyz[i] for i in placed.ids], dtype=float).reshape(-1, 3)
    X = placed.xyz
    off = np.linalg.norm(M - X, axis=1)
    details: Dict[str, object] = {"placed": {i: {"seen_xyz": [round(float(v), 3) for v in x], "map_off_m": float(o),
                                                 "sigma_m": float(sd)}
                                             for i, x, o, sd in zip(placed.ids, X, off, placed.sigma)}}
    limit = p.tolerance + 3.0 * placed.sigma
    if len(placed.ids) == 0:
        return "", details
    details["off_map"] = {i: float(o) for i, o, lim in zip(placed.ids, off, limit) if o > lim}
    n_off = int(np.sum(off > limit))
    if n_off == 0 or (len(placed.ids) >= 2 and n_off * 2 <= len(placed.ids)):
        return None, details  # all or most where the map has them (one off: the self-checks' moved marker)
    seen = (f"marker{'s' if len(off) > 1 else ''} {_ids(placed.ids)} {'are' if len(off) > 1 else 'is'} seen "
            f"{_span(off)} from {'their' if len(off) > 1 else 'its'} map position{'s' if len(off) > 1 else ''}")
    spread = float(np.ptp(X[:, 0]) + np.ptp(X[:, 1])) if len(X) > 1 else 0.0
    models = ["shift"] + (["rotation", "similarity"] if len(placed.ids) >= 2 and spread > 1.0 else [])
    for model in models:
        change = _fit_change(M, X, model)
        if np.all(change.misses <= limit):
            details["change"] = {"model": model, "scale": change.scale, "rotation_deg": math.degrees(change.rotation),
                                 "shift_m": [float(v) for v in change.shift]}
            return f"{seen}: the map looks {_describe(change, origin, p.tolerance)}", details
    worst = _fit_change(M, X, models[-1])
    left = worst.misses > limit
    return (f"{seen}, and no shift, rotation or scale of the map puts them there (markers "
            f"{_ids(np.array(placed.ids)[left])} stay {_span(worst.misses[left])} off): another site's map, or "
            "several markers moved", details)


def _ids(ids) -> str:
    ids = [str(int(i)) for i in ids]
    return ", ".join(ids[:6]) + (f" and {len(ids) - 6} more" if len(ids) > 6 else "")


def _span(metres: np.ndarray) -> str:
    lo, hi = float(np.min(metres)), float(np.max(metres))
    fmt = (lambda v: f"{v:.2f}") if hi < 100 else (lambda v: f"{v:.0f}")
    return f"{fmt(lo)} m" if hi - lo < 0.01 * max(hi, 1.0) else f"{fmt(lo)}-{fmt(hi)} m"


# ----------------------------------------------------------------------------------------------- the check
def _on_track(pt: np.ndarray, t: np.ndarray, p: MapCheckParams) -> np.ndarray:
    """Sightings with prism samples around them (no gap of more than ``max_prism_gap`` s, nor beyond the
    track by the time-offset errors tried)."""
    if len(pt) < 2:
        return np.zeros(len(t), dtype=bool)
    out = (t >= pt[0] + p.max_time_error) & (t <= pt[-1] - p.max_time_error)
    i = np.clip(np.searchsorted(pt, t), 1, len(pt) - 1)
    return out & (pt[i] - pt[i - 1] <= p.max_prism_gap)


def _thinned(s: Sightings, n: int) -> Sightings:
    if len(s.time) <= n:
        return s
    keep = np.unique(np.linspace(0, len(s.time) - 1, n).round().astype(int))
    return Sightings(*(a[keep] for a in s))


def check_map(sightings: Sightings, prism, map_xyz: Mapping[int, Sequence[float]], base_T_camera, prism_in_base,
              params: Optional[MapCheckParams] = None, origin: Optional[Sequence[float]] = None) -> MapVerdict:
    """Whether the map ``map_xyz`` ({id: (3,)} m) fits ``sightings`` seen along the ``prism`` track ((stamps (M,)
    s, positions (M, 3) m), sorted) with the camera at ``base_T_camera`` and the prism at ``prism_in_base`` (m)
    on base_link; ``origin``: the map's (for the message). See the module docstring."""
    p = params or MapCheckParams()
    pt, pp = (np.asarray(a, dtype=float) for a in prism)
    pp = pp.reshape(-1, 3)
    s = Sightings(*(np.asarray(a) for a in sightings))
    known = np.isin(s.id, list(map_xyz)) if len(s.id) else np.zeros(0, dtype=bool)
    s = _thinned(Sightings(*(a[known & _on_track(pt, s.time, p)] for a in s)), p.max_sightings)
    n, markers = len(s.time), sorted({int(i) for i in s.id})
    travel = float(np.sum(np.linalg.norm(np.diff(_prism_at((pt, pp), s.time), axis=0), axis=1))) if n > 1 else 0.0
    if n < p.min_sightings or (len(markers) < 2 and travel < p.min_travel):
        return MapVerdict(UNDETERMINED, f"the marker map is not checked yet: {n} sighting(s) of {len(markers)} "
                          f"marker(s) along {travel:.1f} m of prism track (needs {p.min_sightings} of 2 markers, or "
                          f"{p.min_travel:g} m of travel)", {"sightings": n})
    rays = _rays(s, base_T_camera, prism_in_base)
    M = np.array([map_xyz[int(i)] for i in s.id], dtype=float)
    median, eps, off = _as_is(rays, (pt, pp), M, p)
    fits_as_is = median <= math.radians(p.fit_deg)
    details: Dict[str, object] = {"sightings": n, "markers": markers, "median_off_deg": math.degrees(median),
                                  "time_offset_error_s": eps, "travel_m": travel,
                                  "marker_off_deg": {m: math.degrees(float(np.median(off[s.id == m])))
                                                     for m in markers}}
    # where the markers are seen: with the time offset in use, or the one the map fits best at, whichever
    # the rays agree better with (a wrong offset blurs the places; a wrong map may mimic an offset)
    placed = min((_place(rays, (pt - e, pp), p) for e in sorted({0.0, eps})),  # the prism at t + ε
                 key=lambda pl: pl.misfit)
    named, more = _name_it(placed, map_xyz, p, origin)
    details.update(more)
    summary = f"sightings {math.degrees(median):.1f}° off the map, median of {n}"
    if named is None or (fits_as_is and not named):
        off_map = more.get("off_map") or {}
        note = "".join(f"; marker {i} is seen {o:.2f} m off its map position (moved or wrongly surveyed?)"
                       for i, o in sorted(off_map.items()))
        return MapVerdict(FITS, f"the marker map fits: its markers' sightings are {math.degrees(median):.2f}° off "
                          f"(median of {n}, {len(markers)} markers){note}", details)
    if not named:
        far = float(np.median(np.linalg.norm(M - _prism_at((pt, pp), s.time), axis=1)))
        details["marker_distance_m"] = far
        if far > p.max_marker_distance:  # a marker that far is a pixel: the map and the track are apart
            return MapVerdict(DOES_NOT_FIT, f"the marker map does not fit this recording: its markers "
                              f"{_ids(markers)} are {far / 1000.0:.1f} km from the prism track where they are seen: "
                              f"{_wrong_origin(origin)} or unit ({summary})", details)
        return MapVerdict(DOES_NOT_FIT, f"the marker map does not fit this recording: {summary} (markers "
                          f"{_ids(markers)}); too few sightings from different places to say how (seen over "
                          f"< {p.min_ray_spread_deg:g}° of bearing each)", details)
    return MapVerdict(DOES_NOT_FIT, f"the marker map does not fit this recording: {named} ({summary})", details)


@dataclass
class RollingMapCheck:
    """:func:`check_map` over the last ``window`` s of a live node: ``add_sighting`` and ``add_prism`` (any thread),
    then ``check()`` (tens to hundreds of ms: call it from a worker thread) for the latest :class:`MapVerdict`."""

    map_xyz: Mapping[int, Sequence[float]]
    base_T_camera: np.ndarray
    prism_in_base: np.ndarray
    origin: Optional[Sequence[float]] = None
    window: float = 60.0
    params: Optional[MapCheckParams] = None
    _sightings: Deque[tuple] = field(default_factory=collections.deque)
    _prism: Deque[tuple] = field(default_factory=collections.deque)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def _trim(self, q: Deque[tuple], now: float) -> None:
        while q and q[0][0] < now - self.window:
            q.popleft()

    def add_sighting(self, t: float, marker_id: int, bearing, odom_R) -> None:
        """A marker seen at total-station time ``t`` (s): its unit ``bearing`` in the camera frame, and the odometry's
        rotation of base_link (3×3) then."""
        with self._lock:
            self._sightings.append((float(t), int(marker_id), np.asarray(bearing, dtype=float), np.asarray(odom_R)))
            self._trim(self._sightings, float(t))

    def add_prism(self, t: float, xyz) -> None:
        with self._lock:
            self._prism.append((float(t), np.asarray(xyz, dtype=float)))
            self._trim(self._prism, float(t))

    def check(self) -> MapVerdict:
        with self._lock:  # a copy: the fit runs while the node goes on adding
            sightings, prism = list(self._sightings), sorted(self._prism, key=lambda r: r[0])
        if len(prism) < 2:
            return MapVerdict(UNDETERMINED, "the marker map is not checked yet: no prism track", {})
        track = (np.array([r[0] for r in prism]), np.array([r[1] for r in prism]))
        return check_map(Sightings.from_rows(sightings), track, self.map_xyz, self.base_T_camera, self.prism_in_base,
                         self.params, self.origin)
