"""The network adjustment: every marker's centre from its bearings along the prism-tracked drive.

In: a :class:`~aruco_abs_orient.calibration.Recording` (the marker bearings of every id seen, the odometry, the
prism track on the camera clock, the mounting and lenses as known; its ``marker_map`` holds the control markers,
possibly none), which camera parameters to free (:class:`~.model.MapUnknowns`), the calibration's model knobs and
:class:`~.model.MappingParams`. Out: :class:`~.model.MappingResult` (each marker placed with its covariance,
refused when seen too little, left out when it disagrees), or :class:`~.model.MappingError` saying why nothing
can be placed.

The observation model is the calibration's (``calibration.problem``: the prism, the odometry with the map→odom
yaw δ(t) and its tilt error, the mounting, the lenses' rays, the rolling shutter) with each marker's offset
from its first position free (no prior; a control marker's offset tied to its survey by the survey's σ) and
the least squares its too (``calibration.solve``: robust stage, gate, variance components, the residuals'
correlation in time). The datum is the total station's frame, through the prism track; δ(t) is told by the
track's direction against the odometry and by the bearings themselves (markers seen from several places fix the
camera's heading). First positions: δ(t) from the track headings alone, each observation's lens ray in map, and
per id the point most rays pass near (so a false id cannot pull it), least squares on those. Then the network,
the test of each marker against the others (its residuals against their redundancy; sightings beyond the gate
that meet at a second place, apart from the first beyond both places' σ: the marker moved, or two markers share
the id), the worst failing one left out and the network adjusted again; the control markers tested against the
free network before they tie it.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Dict, List, NamedTuple, Optional, Tuple

import numpy as np

from ..calibration import CalibrationError, CalibrationParams, Recording
from ..calibration.model import N_GLOBALS
from ..calibration.problem import Problem, Setup, setup_problem
from ..calibration.solve import _fit, _Layout, _observation_jacobian, _solve, _Weights
from ..markers import Marker, MarkerMap
from ..solver import yaw_consensus
from .faces import fit_faces
from .model import MappedMarker, MappingError, MappingParams, MappingResult, MapUnknowns, chi2_quantile, format_xyz
from .rays import (
    bias_covariance,
    bias_jacobian,
    diameter,
    normal_matrices,
    rays_in_map,
    scatter_covariance,
    triangulate,
)

__all__ = ["map_markers"]

#: m, the prior σ of a marker's offset without control: none, in effect (it keeps the normal equations regular)
FREE_SIGMA = 100.0
#: rad, rays passing within this of a candidate point count for it in the first positions (δ from the track
#: headings alone is good to a few tenths of a degree)
_FIRST_TOLERANCE = math.radians(1.5)
_CLOCK_ITERATIONS = 4     # Δτ and Δρ are linearised: the clocks are moved by them and the network adjusted again
_FEW_OUTLIERS = 2  # sightings beyond the gate a marker may have without a warning (the gate's own share: 0.03 %)
_TAIL_SHARE = 0.01  # and its share of them: a long drive's tail beyond the gate is 0.1-0.6 % (bench --passes scale)


class _Net(NamedTuple):
    """One adjustment: the setup, the layout, the fit, the globals x0 it started from, the clocks it ran at, the
    detection's σ (rad) of its observations (without the prism's share)."""

    setup: Setup
    lay: _Layout
    fit: object
    x0: np.ndarray
    shift: float
    readout: float
    sigma: np.ndarray

    @property
    def pb(self) -> Problem:
        return self.setup.problem

    def unpack(self):
        return self.lay.unpack(self.fit.p, self.x0)

    def positions(self) -> Dict[int, np.ndarray]:
        """Each marker's adjusted centre (3,) m."""
        _, _, _, off = self.unpack()
        pb = self.pb
        first = np.zeros(len(pb.markers.ids), dtype=int)
        first[pb.markers.index[::-1]] = np.arange(len(pb.markers.index))[::-1]
        return {int(m): pb.M[first[k]] + off[k] for k, m in enumerate(pb.markers.ids)}

    def covariance(self, k: int) -> np.ndarray:
        i = self.lay.offsets[k]
        return self.fit.cov[np.ix_(i, i)].copy()


class _Stats(NamedTuple):
    """Per marker of a network (by its index k): redundancy, test value, test limit, kept and gated sightings,
    RMS residual angle (rad), the covariance (3, 3) m² of its sightings' common error."""

    redundancy: np.ndarray
    test: np.ndarray
    limit: np.ndarray
    kept: np.ndarray
    gated: np.ndarray
    rms: np.ndarray
    bias: np.ndarray

    def covariance(self, net: _Net, k: int) -> np.ndarray:
        """Marker k's position covariance (m²): the network's, scaled by its test where that exceeds 1, and its
        sightings' common error."""
        return net.covariance(k) * max(1.0, float(self.test[k])) + self.bias[k]


def _setup(rec: Recording, params: CalibrationParams, shift: float, readout: float) -> Setup:
    try:
        return setup_problem(rec, params, shift, readout)
    except CalibrationError as e:
        raise MappingError(f"the recording cannot place the markers: {e}") from None


def _size_map(rec: Recording, positions: Dict[int, np.ndarray], priors: Dict[int, Marker], size: float) -> MarkerMap:
    """The markers as the calibration's problem takes them: the first positions with no prior to speak of, the
    control markers ``priors`` as surveyed."""
    markers = [priors[i] if i in priors else Marker(i, np.asarray(positions[i], dtype=float), size, FREE_SIGMA)
               for i in sorted(set(positions) | set(priors))]
    return MarkerMap(markers, rec.marker_map.dictionary, rec.marker_map.frame_id, "the network", rec.marker_map.origin)


def _heading_start(pb: Problem) -> np.ndarray:
    """δ knot values (K,) from the track headings alone (robust), the start of everything."""
    lay = _Layout(pb, (), nuisance=False)
    yh, sh = pb.yaw_head, pb.sigma_head
    sub = np.linspace(0, len(yh) - 1, min(len(yh), 2000)).astype(int)
    p = np.zeros(lay.n + 1)
    p[lay.o_d:lay.o_t] = yaw_consensus(yh[sub], sh[sub], floor=math.radians(2.0))[0]
    weights = _Weights(np.zeros(len(pb.u)), np.ones(len(yh)), True, 1.0, 1.0, 1.0)
    try:
        p, _, _ = _solve(pb, lay, p, np.zeros(N_GLOBALS), weights, pb.params)
    except CalibrationError as e:
        raise MappingError(f"the track headings alone do not determine the map->odom yaw: {e}") from None
    return lay.unpack(p, np.zeros(N_GLOBALS))[1]


def _first_positions(rec: Recording, params: CalibrationParams, mparams: MappingParams, size: float,
                     readout: float, shift: float, seen: List[int]):
    """First positions of the ids ``seen`` and the markers refused for too few views or too short a baseline:
    (positions {id: (3,)}, refused {id: MappedMarker}, (knots, δ knot values) to start the network from)."""
    placeholder = {i: np.zeros(3) for i in seen}
    setup = _setup(replace(rec, marker_map=_size_map(rec, placeholder, {}, size)), params, shift, readout)
    pb = setup.problem
    d = _heading_start(pb)
    org, dirs = rays_in_map(pb, np.zeros(N_GLOBALS), d, np.zeros((len(pb.tilt_knots), 2)))
    tol = max(_FIRST_TOLERANCE, 5.0 * float(np.median(pb.sigma)))
    positions, refused = {}, {}
    for k, mid in enumerate(pb.markers.ids):
        sel = np.flatnonzero(pb.markers.index == k)
        X, inl = triangulate(org[sel], dirs[sel], tol, min_support=mparams.min_views, seed=int(mid))
        used = sel[inl] if X is not None else sel
        marker = _seen(int(mid), X, pb, org[used], used)
        why = _too_little(marker, mparams)
        if X is None or why:
            marker.status, marker.reason = "refused", why or (
                f"its {marker.views} sightings do not meet at one place (seen from {marker.baseline:.1f} m of "
                "track): " + _DRIVE_ADVICE)
            refused[int(mid)] = marker
        else:
            positions[int(mid)] = X
    return positions, refused, (pb.knots.copy(), d)


_DRIVE_ADVICE = ("drive past it so that it is seen from places several metres apart, at 2-8 m, from the front and "
                 "from both sides (doc/field_guide.md, 'Without surveying the markers')")


def _seen(mid: int, X, pb: Problem, origins: np.ndarray, used: np.ndarray) -> MappedMarker:
    """A marker's sighting statistics: images, baseline and ranges of the rays ``used`` (indices into pb)."""
    views = len(np.unique(pb.t[used]))
    ranges = (float("nan"), float("nan"))
    if X is not None and len(used):
        r = np.linalg.norm(X - origins, axis=1)
        ranges = (float(r.min()), float(r.max()))
    return MappedMarker(mid, np.full(3, np.nan) if X is None else X, np.full((3, 3), np.nan), views=views,
                        baseline=diameter(origins), ranges=ranges)


def _too_little(marker: MappedMarker, mparams: MappingParams) -> str:
    if marker.views >= mparams.min_views and marker.baseline >= mparams.min_baseline:
        return ""
    return (f"seen in {marker.views} images (need ≥ {mparams.min_views}) from {marker.baseline:.1f} m of track (need "
            f"≥ {mparams.min_baseline:g} m): " + _DRIVE_ADVICE)


def _adjust(rec: Recording, positions: Dict[int, np.ndarray], priors: Dict[int, Marker], start, size: float,
            params: CalibrationParams, unknowns: MapUnknowns, shift: float, readout: float) -> _Net:
    """The network of the markers ``positions`` (first positions; those in ``priors`` tied to their survey),
    from the δ knots ``start``; Δτ and Δρ, when free, moved into the clocks until they are ≪ 1 ms."""
    net = None
    for _ in range(_CLOCK_ITERATIONS + 1):
        setup = _setup(replace(rec, marker_map=_size_map(rec, positions, priors, size)), params, shift, readout)
        pb = setup.problem
        lay = _Layout(pb, unknowns.free())
        p = np.zeros(lay.n + 1)
        p[lay.o_d:lay.o_t] = np.interp(pb.knots, *start)
        x0 = np.zeros(N_GLOBALS)
        try:
            fit = _fit(pb, lay, p, x0, params)
        except CalibrationError as e:
            raise MappingError(f"the network: {e}") from None
        net = _Net(setup, lay, fit, x0, shift, readout, np.asarray(rec.sigmas, dtype=float)[setup.index])
        x, d, _, _ = net.unpack()
        if abs(x[6]) < params.clock_tolerance and abs(x[7]) < params.clock_tolerance:
            break
        shift, readout = shift + float(x[6]), readout + float(x[7])
        positions = {i: p for i, p in net.positions().items() if i not in priors}
        start = (pb.knots, d)
    return net


def _stats(net: _Net, mparams: MappingParams) -> _Stats:
    """Each marker's test against the others: its kept sightings' normalised square sum over their redundancy
    numbers (≈ 1 when it fits), held to ``noise_spread`` times the χ² quantile of its effective redundancy (its
    redundancy over the residuals' correlation factor)."""
    pb, lay, fit = net.pb, net.lay, net.fit
    x, d, th, off = net.unpack()
    vf = fit.variance_factors
    corr = max(vf.get("markers_correlation", 1.0), 1.0)
    s2 = max(vf["markers"], 1e-12)
    r, J, idx = _observation_jacobian(pb, lay, x, d, th, off)
    C = fit.cov.copy()
    C[lay.n, :] = 0.0
    C[:, lay.n] = 0.0
    w = fit.mask_o / (pb.sigma ** 2 * s2 * corr)       # the weights the covariance was taken with
    red = np.zeros(len(r))
    for lo in range(0, len(r), 4000):
        sl = slice(lo, lo + 4000)
        Cs = C[idx[sl, :, None], idx[sl, None, :]]
        red[sl] = 2.0 - w[sl] * np.einsum("nka,nab,nkb->n", J[sl], Cs, J[sl])
    red = np.where(fit.mask_o, np.clip(red, 0.0, 2.0), 0.0)
    e2 = np.sum(r ** 2, axis=1) / (pb.sigma ** 2 * s2)
    angles = np.linalg.norm(r, axis=1)
    n = len(pb.markers.ids)
    k = pb.markers.index
    kept = np.bincount(k, fit.mask_o, n)
    redundancy = np.bincount(k, red, n)
    test = np.bincount(k, np.where(fit.mask_o, e2, 0.0), n) / np.maximum(redundancy, 1e-9)
    dof = np.maximum(redundancy / corr, 1.0)
    limit = np.array([mparams.noise_spread * chi2_quantile(v, mparams.test_alpha) / v for v in dof])
    gated = np.bincount(k, ~fit.mask_o, n)
    rms = np.sqrt(np.bincount(k, np.where(fit.mask_o, angles ** 2, 0.0), n) / np.maximum(kept, 1))
    sigma_b = np.full(n, math.radians(mparams.bias_deg))
    w0 = fit.mask_o / pb.sigma ** 2
    bias = bias_covariance(k, normal_matrices(k, n, J[:, :, -3:], w0), J[:, :, -3:], bias_jacobian(pb.u), w0, sigma_b)
    return _Stats(redundancy, test, limit, kept.astype(int), gated.astype(int), rms, bias)


def _second_place(net: _Net, k: int, at: np.ndarray, rays, mparams: MappingParams) -> Optional[np.ndarray]:
    """Where the gated sightings of marker k meet (``rays``: every observation's, :func:`rays_in_map`), when
    enough of them do (``min_views`` and ``moved_share`` of its sightings) from a long enough baseline, and that
    place differs from the marker's (``at``) beyond both their σ (χ² of 3 degrees of freedom at ``test_alpha``;
    the second place's σ from its rays' own scatter, their correlation in time included): the marker moved during
    the recording, or a second marker has its id. Sightings a little off everywhere (near a seam, on a precise
    network) meet near the marker itself: not a second place."""
    pb = net.pb
    mine = pb.markers.index == k
    sel = np.flatnonzero(mine & ~net.fit.mask_o)
    enough = max(mparams.min_views, int(math.ceil(mparams.moved_share * np.count_nonzero(mine))))
    if len(sel) < enough:
        return None
    org, dirs = rays
    X, inl = triangulate(org[sel], dirs[sel], _FIRST_TOLERANCE, min_support=enough, seed=k)
    if X is None or diameter(org[sel][inl]) < mparams.min_baseline:
        return None
    corr = max(net.fit.variance_factors.get("markers_correlation", 1.0), 1.0)
    diff = X - at
    C = net.covariance(k) + corr * scatter_covariance(X, org[sel][inl], dirs[sel][inl])
    if float(diff @ np.linalg.solve(C, diff)) <= chi2_quantile(3.0, mparams.test_alpha):
        return None
    return X


def _failing(net: _Net, st: _Stats, mparams: MappingParams) -> Dict[int, Tuple[float, str]]:
    """The markers (by index) that disagree with the others: how badly (for picking the worst) and why."""
    pb = net.pb
    out = {}
    positions = net.positions()
    x, d, th, _ = net.unpack()
    rays = rays_in_map(pb, x, d, th)
    for k, mid in enumerate(pb.markers.ids):
        total = st.kept[k] + st.gated[k]
        second = _second_place(net, k, positions[int(mid)], rays, mparams) if st.gated[k] else None
        if second is not None:
            moved = float(np.linalg.norm(second - positions[int(mid)]))
            out[k] = (np.inf, f"{st.gated[k]} of its {total} sightings meet {1e3 * moved:.0f} mm from the others "
                              f"(at {format_xyz(second)}): it moved during the recording, or two markers carry id "
                              f"{int(mid)}")
        elif st.test[k] > st.limit[k]:
            out[k] = (st.test[k] / st.limit[k], f"it disagrees with the other markers (its residuals "
                                                f"{math.degrees(st.rms[k]):.3f}° RMS, test {st.test[k]:.2f} against "
                                                f"≤ {st.limit[k]:.2f})")
    return out


def map_markers(rec: Recording, corners: Optional[np.ndarray] = None, size: float = 0.19,
                unknowns: Optional[MapUnknowns] = None, params: Optional[CalibrationParams] = None,
                mparams: Optional[MappingParams] = None, readout: float = 0.0) -> MappingResult:
    """Place every marker of a recording.

    Args:
        rec: the bearings of every id seen (``obs_*``, ``bearings``, ``sigmas``), the odometry, the prism track on
            the camera clock, the mounting and lenses as known (``calibration.Recording``); its ``marker_map``:
            the control markers (may be empty), whose survey (with its σ) ties the map further when it agrees
            with the network.
        corners: (N, 4, 3) the corner bearings of each observation (ArUco order), or None: the face normals are
            fitted to them, the centres fixed.
        size: the markers' black-square side (m; a control marker's own size wins).
        unknowns: which camera parameters the network estimates (default none: the mounting, readout, time offset
            and lenses given are kept).
        params: the network's model (``CalibrationParams``: knots, heading constraints, gates; its
            ``drift_walk_estimated`` is ``mparams``'). ``heading_model`` "auto" is the VO's direction of travel
            here (the prism track against the track the VO predicts for the prism: a platform's crab and weave
            cancel), the VO's yaw when its track cannot tell δ (an odometry without positions), with a warning.
        mparams: :class:`~.model.MappingParams`.
        readout: the camera's rolling-shutter readout (s), fixed or the start of its estimate.

    Raises:
        MappingError: malformed inputs, or a recording that places no marker (why, and what to drive).
    """
    unknowns = unknowns or MapUnknowns()
    params = params or CalibrationParams()
    params.validate()
    mparams = mparams or MappingParams()
    params = replace(params, drift_walk_estimated=mparams.drift_walk_estimated)
    if not (math.isfinite(size) and size > 0):
        raise MappingError(f"size: expected the markers' side in metres > 0, got {size!r}")
    if not (math.isfinite(readout) and 0.0 <= readout < 1.0):
        raise MappingError(f"readout: expected seconds in [0, 1), got {readout!r}")
    ids = np.asarray(rec.obs_ids).ravel()
    if corners is not None:
        corners = np.asarray(corners, dtype=float)
        if corners.shape != (len(ids), 4, 3):
            raise MappingError(f"corners: expected an array of shape ({len(ids)}, 4, 3), got {corners.shape}")
    if params.heading_model != "auto":
        return _map_markers(rec, corners, size, unknowns, params, mparams, readout)
    try:
        return _map_markers(rec, corners, size, unknowns, replace(params, heading_model="vo_track"), mparams, readout)
    except MappingError as e:
        result = _map_markers(rec, corners, size, unknowns, replace(params, heading_model="vo_yaw"), mparams, readout)
        result.warnings.append(f"the odometry's direction of travel could not tell the map->odom yaw ({e}): its "
                               "yaw did, base_link x taken as the direction of travel (a platform that crabs "
                               "biases it)")
        return result


def _map_markers(rec: Recording, corners: Optional[np.ndarray], size: float, unknowns: MapUnknowns,
                 params: CalibrationParams, mparams: MappingParams, readout: float) -> MappingResult:
    """:func:`map_markers` with a heading model chosen and the inputs checked."""
    seen = sorted({int(i) for i in np.asarray(rec.obs_ids).ravel()})
    positions, refused, start = _first_positions(rec, params, mparams, size, readout, 0.0, seen)
    if len(positions) < params.min_markers:
        raise MappingError(f"only {len(positions)} of the {len(seen)} markers seen were seen enough to place: "
                           + "; ".join(f"{m.id}: {m.reason}" for m in refused.values()))
    left_out: Dict[int, MappedMarker] = {}
    net = _adjust(rec, positions, {}, start, size, params, unknowns, 0.0, readout)
    while True:
        st = _stats(net, mparams)
        failing = _failing(net, st, mparams)
        if not failing or len(positions) - 1 < params.min_markers:
            break
        k = max(failing, key=lambda j: failing[j][0])
        mid = int(net.pb.markers.ids[k])
        left_out[mid] = _marker(net, st, k, mid, status="left out", reason=failing[k][1])
        del positions[mid]
        start = (net.pb.knots, net.unpack()[1])
        net = _adjust(rec, positions, {}, start, size, params, unknowns, net.shift, net.readout)
    controls = _test_controls(net, st, rec.marker_map, mparams)
    priors = {i: rec.marker_map[i] for i, (_, _, used) in controls.items() if used}
    if priors:
        start = (net.pb.knots, net.unpack()[1])
        net = _adjust(rec, net.positions(), priors, start, size, params, unknowns, net.shift, net.readout)
        st = _stats(net, mparams)
    return _result(rec, net, st, corners, size, mparams, refused, left_out, controls)


def _test_controls(net: _Net, st: _Stats, control: MarkerMap,
                   mparams: MappingParams) -> Dict[int, Tuple[np.ndarray, float, bool]]:
    """Each control marker the network placed: (its survey, the network's normalised difference from it (√χ²,
    3 degrees of freedom, the survey's σ and the network's covariance), whether it agrees and ties the map)."""
    out = {}
    limit = chi2_quantile(3.0, mparams.test_alpha)
    positions = net.positions()
    for k, mid in enumerate(net.pb.markers.ids):
        mid = int(mid)
        if mid not in control:
            continue
        c = control[mid]
        diff = positions[mid] - c.position
        chi2 = float(diff @ np.linalg.solve(st.covariance(net, k) + c.sigma ** 2 * np.eye(3), diff))
        out[mid] = (c.position.copy(), math.sqrt(chi2), chi2 <= limit)
    return out


def _marker(net: _Net, st: _Stats, k: int, mid: int, status: str = "mapped", reason: str = "") -> MappedMarker:
    pb = net.pb
    sel = np.flatnonzero((pb.markers.index == k) & net.fit.mask_o)
    x, d, th, _ = net.unpack()
    org, _ = rays_in_map(pb, x, d, th)
    m = _seen(mid, net.positions()[mid], pb, org[sel], sel)
    return replace(m, cov=st.covariance(net, k), redundancy=float(st.redundancy[k]), test=float(st.test[k]),
                   test_limit=float(st.limit[k]), outliers=int(st.gated[k]), rms=float(st.rms[k]), status=status,
                   reason=reason)


def _result(rec: Recording, net: _Net, st: _Stats, corners, size: float, mparams: MappingParams,
            refused: Dict[int, MappedMarker], left_out: Dict[int, MappedMarker], controls) -> MappingResult:
    pb, fit = net.pb, net.fit
    x, d, th, _ = net.unpack()
    markers: Dict[int, MappedMarker] = dict(refused)
    markers.update(left_out)
    warnings = []
    for k, mid in enumerate(pb.markers.ids):
        mid = int(mid)
        m = _marker(net, st, k, mid)
        if mid in controls:
            m.control = controls[mid]
            if not controls[mid][2]:
                off = 1e3 * float(np.linalg.norm(m.position - controls[mid][0]))
                warnings.append(f"control marker {mid}: the network puts it {off:.1f} mm from its survey "
                                f"({controls[mid][1]:.1f} σ): its survey is not used (re-survey it, or was it moved?)")
        worst = float(np.sqrt(np.max(np.linalg.eigvalsh(m.cov))))
        too_little = _too_little(m, mparams)
        if too_little or not worst <= mparams.max_sigma:
            m.status, m.reason = "refused", too_little or (
                f"placed only to ± {1e3 * worst:.1f} mm (1-σ, worst axis; limit {1e3 * mparams.max_sigma:.0f} mm), "
                f"seen in {m.views} images from {m.baseline:.1f} m of track at {m.ranges[0]:.1f}-{m.ranges[1]:.1f} m: "
                + _DRIVE_ADVICE)
        elif worst > mparams.loose_sigma:
            warnings.append(f"marker {mid}: placed only to ± {1e3 * worst:.1f} mm (1-σ, worst axis), seen in {m.views} "
                            f"images from {m.baseline:.1f} m of track at {m.ranges[0]:.1f}-{m.ranges[1]:.1f} m: "
                            "process and the node weigh it by that; to place it better, " + _DRIVE_ADVICE)
        if m.status == "mapped" and m.outliers > max(_FEW_OUTLIERS, _TAIL_SHARE * (m.outliers + m.views)):
            warnings.append(f"marker {mid}: {m.outliers} of its sightings agree with no position (false ids or "
                            "reflections): left out of it")
        markers[mid] = m
    if corners is not None:
        index = net.setup.index
        faces = fit_faces(pb, x, d, th, corners[index], np.asarray(rec.sigmas, dtype=float)[index], fit.mask_o,
                          net.positions(), size, math.radians(mparams.bias_deg))
        for mid, (normal, sigma) in faces.items():
            if mid in markers and sigma <= math.radians(mparams.max_normal_sigma_deg):
                markers[mid].normal, markers[mid].normal_sigma = normal, sigma
    sd = np.sqrt(np.maximum(np.diag(fit.cov), 0.0))
    sd_x = np.full(N_GLOBALS, np.nan)
    sd_x[list(net.lay.free)] = sd[:net.lay.G]
    n = len(net.setup.usable)
    used = np.zeros(n, dtype=bool)
    used[net.setup.index[fit.mask_o]] = True
    skipped = dict(net.setup.skipped)
    beyond = int(np.count_nonzero(net.setup.usable & ~used))
    if beyond:
        skipped["beyond the gate"] = beyond
    knots, vf = net.pb.knots, fit.variance_factors
    walk = net.pb.drift_sigma * math.sqrt(vf["drift"] / (knots[1] - knots[0])) if "drift" in vf else float("nan")
    return MappingResult(markers=markers, boresight=x[:3].copy(), boresight_sigma=sd_x[:3].copy(),
                         readout=net.readout, readout_sigma=float(sd_x[7]), time_offset_delta=net.shift,
                         time_offset_sigma=float(sd_x[6]), lenses=pb.lenses_at(x),
                         variance_factors=dict(fit.variance_factors), heading_model=pb.params.heading_model,
                         n_observations=n, n_used=int(used.sum()), skipped=skipped,
                         yaw_drift=float((d[-1] - d[0]) / (knots[-1] - knots[0])), yaw_walk=walk,
                         drive=np.asarray(rec.prism_positions, dtype=float)[::10].copy(), warnings=warnings)

