"""Solving the calibration problem: robust weighted least squares, honest σ, the platform model, the entry point.

In: the observations of a recording (a :class:`~.model.Recording`), which unknowns to free
(:class:`~.model.Unknowns`) and :class:`~.model.CalibrationParams`. Out: a :class:`~.model.Calibration`
(boresight, lever arm, time offset, readout, lenses with their covariance, the odometry's tilt, the markers'
offsets, residuals, the platform model used and why), or :class:`~.model.CalibrationError` saying why the
recording cannot determine it.

Gauss-Newton over the free globals, the knots of δ(t) and of the odometry's tilt, and the markers' offsets
(``problem``): a Cauchy-weighted robust stage, a gate at ``outlier_gate`` σ, then least squares with the
variance factors of three groups estimated (the bearings, the track headings, the markers' offsets: variance
component estimation, the last never below the survey's σ), the covariance inflated for the residuals'
correlation in time (all of them, and each marker's own) and for the markers' pattern biases (``bias``).
Δτ and Δρ are linearised: :func:`calibrate` moves the clocks by them and solves again.
The heading model ``auto`` fits the recording both ways and keeps the VO's yaw unless a Hausman test says the
platform crabs (the two boresight yaws differ beyond the σ of their difference) or the VO's direction of
travel determines the boresight yaw better.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Dict, List, NamedTuple, Optional, Tuple

import numpy as np

from ..solver import yaw_consensus
from .bias import pattern_bias_covariance
from .model import N_GLOBALS, Calibration, CalibrationError, CalibrationParams, Recording, Unknowns
from .problem import Problem, setup_problem
from .variance import bearings_correlation, correlation_factor, walk_variance_factor

__all__ = ["calibrate"]

_H = 1e-6            # step of the central differences (rad, m, s)
_CHUNK = 4000        # observations per block of the normal equations (memory)
_ROBUST_ITERATIONS = 8   # Gauss-Newton steps of the robust (Cauchy) stage
_LENS_SHARE = 0.2        # a lens that saw at least this share of the observations must determine its yaw


def _cauchy(e: np.ndarray, k: float) -> np.ndarray:
    return 1.0 / (1.0 + (e / k) ** 2)


class _Layout:
    """Where each unknown sits in the parameter vector p = [free globals][δ knots][tilt knots (x, y)][marker
    offsets (x, y, z)], and the sink index n for fixed ones (a tilt knot 0 with ``odom_levelled``; the tilt and
    the offsets without ``nuisance``: the fit "before", of δ alone)."""

    def __init__(self, pb: Problem, free: Tuple[int, ...], nuisance: bool = True):
        self.free = tuple(free)
        self.G, self.K, self.Kt, self.Nm = len(free), len(pb.knots), len(pb.tilt_knots), len(pb.markers.ids)
        self.o_d = self.G
        self.o_t = self.o_d + self.K
        fixed = self.Kt if not nuisance else 1 if pb.params.odom_levelled else 0   # θ(knot 0) = 0: levelled
        self.o_m = self.o_t + 2 * (self.Kt - fixed)
        self.n = self.o_m + (3 * self.Nm if nuisance else 0)
        self.tilt = np.full((self.Kt, 2), self.n)
        self.tilt[fixed:] = self.o_t + np.arange(2 * (self.Kt - fixed)).reshape(-1, 2)
        self.offsets = (self.o_m + np.arange(3 * self.Nm).reshape(self.Nm, 3) if nuisance
                        else np.full((self.Nm, 3), self.n))

    def unpack(self, p: np.ndarray, x0: np.ndarray):
        """(x (N_GLOBALS,), d (K,), θ (Kt, 2), offsets (Nm, 3)) of p (n + 1,), the fixed globals from x0."""
        x = x0.copy()
        x[list(self.free)] = p[:self.G]
        return x, p[self.o_d:self.o_t], p[self.tilt], p[self.offsets]      # p[n], the sink, stays 0


class _Weights(NamedTuple):
    """How :func:`_solve` weights the groups: ``mask_o``/``mask_h`` (0/1 per marker observation / heading
    constraint), ``robust`` (Cauchy IRLS on top), ``scale_o``/``scale_h``/``scale_m``/``scale_d`` (multiply the
    a-priori σ of the bearings, the headings, the markers' offsets and δ's walk)."""

    mask_o: np.ndarray
    mask_h: np.ndarray
    robust: bool
    scale_o: float
    scale_h: float
    scale_m: float
    scale_d: float = 1.0


class _Fit(NamedTuple):
    """:func:`_fit`'s result: the parameter vector, the covariance of p, the observations and heading constraints
    kept, the variance factors of the groups and the iterations."""

    p: np.ndarray
    cov: np.ndarray
    mask_o: np.ndarray
    mask_h: np.ndarray
    variance_factors: Dict[str, float]
    iterations: int


def _accumulate(H: np.ndarray, g: np.ndarray, idx: np.ndarray, J: np.ndarray, r: np.ndarray, w: np.ndarray) -> None:
    """H += Σ Jᵀ w J and g += Σ Jᵀ w r over residual blocks: ``J`` (N, k, s) local Jacobians whose s columns
    are the parameters ``idx`` (N, s), ``r`` (N, k), ``w`` (N,); in place."""
    n = H.shape[0]
    for lo in range(0, len(r), _CHUNK):
        sl = slice(lo, lo + _CHUNK)
        Jw = J[sl] * w[sl, None, None]
        blocks = np.einsum("nka,nkb->nab", Jw, J[sl])
        ii = idx[sl]
        H += np.bincount((ii[:, :, None] * n + ii[:, None, :]).ravel(), blocks.ravel(), minlength=n * n).reshape(n, n)
        g += np.bincount(ii.ravel(), np.einsum("nka,nk->na", Jw, r[sl]).ravel(), minlength=n)


def _observation_jacobian(pb: Problem, lay: _Layout, x, d, th, off) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals (N, 3), their local Jacobians (N, 3, G + 9) and the parameter of each column (N, G + 9): the
    free globals, δ's two knots, θ's two knots (x, y each), the marker's offset (x, y, z)."""
    r, Jg, c, ct, cm = pb.linearise(x, *pb.local(d, th, off), free=lay.free, h=_H)
    N, G = len(r), lay.G
    J = np.empty((N, 3, G + 9))
    J[:, :, :G] = Jg[:, :, list(lay.free)]
    a = pb.a_obs[:, None]
    J[:, :, G], J[:, :, G + 1] = (1.0 - a) * c, a * c
    at = pb.a_tilt[:, None, None]
    J[:, :, G + 2:G + 4], J[:, :, G + 4:G + 6] = (1.0 - at) * ct, at * ct
    J[:, :, G + 6:] = cm
    idx = np.empty((N, G + 9), dtype=np.int64)
    idx[:, :G] = np.arange(G)
    idx[:, G] = lay.o_d + pb.i_obs
    idx[:, G + 1] = lay.o_d + pb.i_obs + 1
    it = pb.i_tilt
    it1 = np.minimum(it + 1, lay.Kt - 1)
    idx[:, G + 2:G + 4] = lay.tilt[it]
    idx[:, G + 4:G + 6] = lay.tilt[it1]
    idx[:, G + 6:] = lay.offsets[pb.markers.index]
    return r, J, idx


def _normal_equations(pb: Problem, lay: _Layout, p: np.ndarray, x0: np.ndarray, weights: _Weights,
                      params: CalibrationParams, linear: Optional[Tuple[np.ndarray, np.ndarray, np.ndarray]] = None):
    """(H, g) of the weighted problem at p (size n + 1, the sink last), with the robust weights when asked;
    ``linear``: :func:`_observation_jacobian` at p when already computed."""
    mask_o, mask_h, robust, scale_o, scale_h = weights[:5]
    x, d, th, off = lay.unpack(p, x0)
    n1 = lay.n + 1
    H = np.zeros((n1, n1))
    g = np.zeros(n1)
    r, J, idx = linear if linear is not None else _observation_jacobian(pb, lay, x, d, th, off)
    sig = pb.sigma * scale_o
    w = mask_o / sig ** 2
    rh = pb.heading_residuals(x, d)
    sigh = pb.sigma_head * scale_h
    wh = mask_h / sigh ** 2
    if robust:
        e = np.linalg.norm(r, axis=1) / sig
        eh = np.abs(rh) / sigh
        k_o = max(params.loss_scale, 2.0 * float(np.median(e[mask_o > 0]))) if np.any(mask_o > 0) else 1.0
        k_h = max(params.loss_scale, 2.0 * float(np.median(eh[mask_h > 0]))) if np.any(mask_h > 0) else 1.0
        w = w * _cauchy(e, k_o)
        wh = wh * _cauchy(eh, k_h)
    _accumulate(H, g, idx, J, r, w)
    # the track headings: δ at two knots, and Δτ (∂/∂Δτ = the turn rate) when it is free
    Jh = np.zeros((len(rh), 1, 3))
    Jh[:, 0, 0], Jh[:, 0, 1] = 1.0 - pb.a_head, pb.a_head
    ih = np.empty((len(rh), 3), dtype=np.int64)
    ih[:, 0], ih[:, 1] = lay.o_d + pb.i_head, lay.o_d + pb.i_head + 1
    if 6 in lay.free:
        Jh[:, 0, 2], ih[:, 2] = pb.rate_head, lay.free.index(6)
    else:
        ih[:, 2] = lay.n
    _accumulate(H, g, ih, Jh, rh[:, None], wh)
    _add_priors(H, g, pb, lay, (x, d, th, off), weights, params)
    H[lay.n, :] = 0.0                       # the sink: fixed parameters stay 0
    H[:, lay.n] = 0.0
    H[lay.n, lay.n] = 1.0
    g[lay.n] = 0.0
    return H, g


def _add_priors(H: np.ndarray, g: np.ndarray, pb: Problem, lay: _Layout, values, weights: _Weights,
                params: CalibrationParams) -> None:
    """H and g with the priors at ``values`` (x, d, θ, offsets), in place: δ a random walk (about a free rate
    with ``drift_walk_estimated``), each tilt knot tied to 0 and to its neighbour, the lenses to the nominal ones,
    each marker's offset to 0."""
    x, d, th, off = values
    wd = 1.0 / (pb.drift_sigma * weights.scale_d) ** 2
    diffs = [(np.arange(lay.o_d, lay.o_t - 1), np.arange(lay.o_d + 1, lay.o_t), wd, np.diff(d))]
    if params.drift_walk_estimated:     # a walk about a free rate: the increments' mean out (rank 1, the ends)
        ends, sgn = np.array([lay.o_d, lay.o_t - 1]), np.array([-1.0, 1.0])
        H[np.ix_(ends, ends)] -= wd / (lay.K - 1) * np.outer(sgn, sgn)
        g[ends] -= wd / (lay.K - 1) * sgn * (d[-1] - d[0])
    if lay.Kt > 1:
        dth = np.diff(th, axis=0).ravel()
        diffs.append((lay.tilt[:-1].ravel(), lay.tilt[1:].ravel(), 1.0 / pb.tilt_drift_sigma ** 2, dth))
    for ia, ib, wp, dv in diffs:
        np.add.at(H, (ia, ia), wp)
        np.add.at(H, (ib, ib), wp)
        np.add.at(H, (ia, ib), -wp)
        np.add.at(H, (ib, ia), -wp)
        np.add.at(g, ia, -wp * dv)
        np.add.at(g, ib, wp * dv)
    ti = lay.tilt.ravel()
    np.add.at(H, (ti, ti), 1.0 / pb.tilt_sigma ** 2)
    np.add.at(g, ti, th.ravel() / pb.tilt_sigma ** 2)
    rot_prior = math.radians(params.lens_rotation_prior_deg)
    for gl, sp in ((8, params.lens_offset_prior), (9, rot_prior), (10, rot_prior), (11, rot_prior)):
        if gl in lay.free:      # the lenses: around the nominal ones
            j = lay.free.index(gl)
            H[j, j] += 1.0 / sp ** 2
            g[j] += x[gl] / sp ** 2
    wm = 1.0 / np.repeat(pb.markers.sigma * weights.scale_m, 3) ** 2
    mi = lay.offsets.ravel()
    H[mi, mi] += wm
    g[mi] += wm * off.ravel()


def _solve(pb: Problem, lay: _Layout, p: np.ndarray, x0: np.ndarray, weights: _Weights,
           params: CalibrationParams) -> Tuple[np.ndarray, int, np.ndarray]:
    """Gauss-Newton from p; the solution, the iterations and the normal matrix of the last one (at the solution
    but for its last step, below 1e-9 once converged: the covariance's)."""
    iterations = 0
    for iterations in range(1, params.max_iterations + 1):  # noqa: B007  (reported)
        H, g = _normal_equations(pb, lay, p, x0, weights, params)
        try:
            dp = -np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            raise CalibrationError("the normal equations are singular: the recording does not determine "
                                   "the calibration (too few markers or no motion)") from None
        if not np.all(np.isfinite(dp)):
            raise CalibrationError("the normal equations are singular: the recording does not determine "
                                   "the calibration (too few markers or no motion)")
        p = p + dp
        if float(np.max(np.abs(dp))) < 1e-9:    # rad, m, s: far below any σ
            break
    return p, iterations, H


def _inverse(H: np.ndarray) -> np.ndarray:
    """The covariance from a normal matrix (CalibrationError when it is singular)."""
    cov = np.linalg.inv(H)
    if not np.all(np.isfinite(cov)):
        raise CalibrationError("the normal equations are singular: the recording does not determine "
                               "the calibration (too few markers or no motion)")
    return cov


def _normalised(pb: Problem, lay: _Layout, p, x0, weights: _Weights) -> Tuple[np.ndarray, np.ndarray]:
    """|residual| / σ of the bearings (N,) and of the headings (Nh,) at p."""
    x, d, th, off = lay.unpack(p, x0)
    e = np.linalg.norm(pb.residuals(x, *pb.local(d, th, off)), axis=1) / (pb.sigma * weights.scale_o)
    eh = np.abs(pb.heading_residuals(x, d)) / (pb.sigma_head * weights.scale_h)
    return e, eh


def _angles(pb: Problem, lay: _Layout, p, x0) -> np.ndarray:
    """Angle (rad) between observed and predicted bearings."""
    x, d, th, off = lay.unpack(p, x0)
    pred = pb.predict(x, *pb.local(d, th, off))
    return np.arctan2(np.linalg.norm(np.cross(pb.u, pred), axis=1), np.sum(pb.u * pred, axis=1))


def _fit(pb: Problem, lay: _Layout, p: np.ndarray, x0: np.ndarray, params: CalibrationParams) -> _Fit:
    """Robust stage, gate, least squares with variance component estimation, covariance."""
    n_o, n_h = len(pb.u), len(pb.yaw_head)
    weights = _Weights(np.ones(n_o), np.ones(n_h), True, 1.0, 1.0, 1.0)
    # the robust stage only has to find the outliers for the gate: a few reweightings do
    robust = replace(params, max_iterations=min(params.max_iterations, _ROBUST_ITERATIONS))
    p, it, _ = _solve(pb, lay, p, x0, weights, robust)
    vf = {"markers": float("nan"), "heading": float("nan"), "marker_positions": float("nan")}
    cov = None
    for _ in range(5):
        e, eh = _normalised(pb, lay, p, x0, weights)
        # a 2-D residual: gate on its norm; heading: on its absolute value
        weights = weights._replace(mask_o=(e <= params.outlier_gate).astype(float),
                                   mask_h=(eh <= params.outlier_gate).astype(float), robust=False)
        p, it2, H = _solve(pb, lay, p, x0, weights, params)
        it += it2
        cov = _inverse(H)
        e, eh = _normalised(pb, lay, p, x0, weights)
        mo, mh = weights.mask_o, weights.mask_h
        f_o = float(np.sum(mo * e ** 2) / max(2.0 * mo.sum(), 1.0))
        f_h = float(np.sum(mh * eh ** 2) / max(mh.sum(), 1.0)) if n_h else 1.0
        # the markers' offsets: their squares over the a-priori σ against their redundancy (Helmert)
        wm = 1.0 / np.repeat(pb.markers.sigma * weights.scale_m, 3) ** 2
        mi = lay.offsets.ravel()
        if mi[0] < lay.n:       # the offsets are estimated
            redundancy = max(3 * lay.Nm - float(np.sum(np.diag(cov)[mi] * wm)), 1e-3)
            f_m = float(np.sum(p[mi] ** 2 * wm) / redundancy)
        else:
            f_m = 1.0
        vf = {"markers": f_o * weights.scale_o ** 2, "heading": f_h * weights.scale_h ** 2 if n_h else float("nan"),
              "marker_positions": f_m * weights.scale_m ** 2}
        scale_m = max(1.0, weights.scale_m * math.sqrt(max(f_m, 1e-6)))   # never below the survey's σ
        f_d = 1.0
        if params.drift_walk_estimated:
            f = walk_variance_factor(p[lay.o_d:lay.o_t], cov[lay.o_d:lay.o_t, lay.o_d:lay.o_t],
                                     pb.drift_sigma * weights.scale_d)
            if math.isfinite(f):        # NaN: too few knots tell the walk, its prior stays
                f_d = f
                vf["drift"] = f_d * weights.scale_d ** 2
        done = (abs(f_o - 1.0) < 0.05 and abs(f_h - 1.0) < 0.05 and abs(scale_m / weights.scale_m - 1.0) < 0.05
                and abs(f_d - 1.0) < 0.05)
        weights = weights._replace(scale_o=weights.scale_o * math.sqrt(max(f_o, 1e-6)),
                                   scale_h=weights.scale_h * math.sqrt(max(f_h, 1e-6)), scale_m=scale_m,
                                   scale_d=weights.scale_d * math.sqrt(max(f_d, 1e-6)))
        if done:
            break
    # the residuals are correlated in time (the VO's yaw walk between knots, the smoothed track heading, a
    # platform that wanders): n correlated residuals weigh like n / c independent ones. The covariance is taken
    # with each group's σ inflated by √c, c from the residuals' own autocorrelation; the estimate keeps the
    # weights above.
    x, d, th, off = lay.unpack(p, x0)
    linear = _observation_jacobian(pb, lay, x, d, th, off)
    r_o = linear[0] / pb.sigma[:, None]
    c_o = bearings_correlation(r_o, pb.t, pb.markers.index, weights.mask_o > 0)
    c_h = correlation_factor((pb.heading_residuals(x, d) / pb.sigma_head)[weights.mask_h > 0, None]) if n_h else 1.0
    vf.update({"markers_correlation": c_o, "heading_correlation": c_h})
    cov = _inverse(_normal_equations(pb, lay, p, x0, weights._replace(scale_o=weights.scale_o * math.sqrt(c_o),
                                                                      scale_h=weights.scale_h * math.sqrt(c_h)),
                                     params, linear)[0])
    if np.any(pb.bias > 0):    # the markers' pattern biases: the same on every frame (calibration.bias)
        _, J, idx = linear
        cov = cov + pattern_bias_covariance(_normal_equations(pb, lay, p, x0, weights, params, linear)[0], J, idx,
                                            weights.mask_o / (pb.sigma * weights.scale_o) ** 2, pb.u,
                                            pb.predict(x, *pb.local(d, th, off)), pb.bias, pb.markers.index, lay.n)
    return _Fit(p, cov, weights.mask_o.astype(bool), weights.mask_h.astype(bool), vf, it)


def calibrate(rec: Recording, unknowns: Optional[Unknowns] = None, params: Optional[CalibrationParams] = None,
              readout: float = 0.0) -> Calibration:
    """Boresight (and optionally lever arm, time offset, readout, lenses) of the camera from all marker
    observations of a recording.

    Args:
        rec: the observations, odometry, prism track, marker map, nominal lever arms and lenses, on one clock
            (:class:`~.model.Recording`; ids not in the map and observations without a prism position are
            skipped and counted).
        unknowns: which parameters beside the boresight are freed (:class:`~.model.Unknowns`, default none):
            ``lever_arm`` the camera origin in base_link; ``time_offset`` the residual time offset Δτ (s) of the
            prism stamps given (linearised, so the offset given should be within ~0.1 s, as
            ``timesync.estimate_offset`` gives it); ``readout`` the rolling-shutter readout time, starting from
            ``readout`` (needs turns with markers above and below the horizon); ``lenses`` the two lenses'
            offset and relative rotation, starting from ``rec.lenses`` (needs markers at several ranges on both
            sides of the camera).
        params: :class:`CalibrationParams` (its ``heading_model``: see the module docstring).
        readout: the camera's rolling-shutter readout time (s; 0 = global shutter), fixed or the start of its
            estimate: an observation is captured at ``obs_times + obs_rows · readout``.

    Raises:
        CalibrationError: malformed inputs, or a recording that cannot determine the calibration (no
            markers, too few observations, no driving for the boresight yaw, parameters whose σ exceed
            the limits) — the message says which, why, and what to record or which option to try.
    """
    if not (math.isfinite(readout) and 0.0 <= readout < 1.0):
        raise CalibrationError(f"readout: expected seconds in [0, 1), got {readout!r}")
    unknowns = unknowns or Unknowns()
    params = params or CalibrationParams()
    params.validate()
    if params.heading_model == "auto":
        cal, model, reason = _choose_heading_model(rec, unknowns, params, readout)
    else:
        model, reason = params.heading_model, "as asked (heading_model)"
        cal = _calibrate_once(rec, unknowns, params, 0.0, readout)
    params = replace(params, heading_model=model)
    shift, readout = cal.time_offset_delta, readout + cal.readout
    for _ in range(4):  # Δτ, Δρ are linearised: move the clocks by them and solve again until they are small
        if abs(cal.time_offset_delta) < params.clock_tolerance and abs(cal.readout) < params.clock_tolerance:
            break
        cal = _calibrate_once(rec, unknowns, params, shift, readout)
        shift += cal.time_offset_delta
        readout += cal.readout
    cal.time_offset_delta, cal.readout = shift, readout
    cal.heading_model, cal.heading_model_reason = model, reason
    cal.warnings = _check_determined(cal, unknowns, params)
    return cal


def _choose_heading_model(rec: Recording, unknowns: Unknowns, params: CalibrationParams,
                          readout: float) -> Tuple[Calibration, str, str]:
    """Both heading models fitted; the VO's yaw kept unless the platform crabs (a Hausman test on the boresight
    yaw: under "no crab" the VO's yaw is the efficient estimate and the VO's direction of travel a consistent
    one, so their difference has variance σ_track² − σ_yaw²) or the direction of travel is the more precise.
    Returns the chosen calibration, the model and the reason (one line, degrees)."""
    by_yaw = _calibrate_once(rec, unknowns, replace(params, heading_model="vo_yaw"), 0.0, readout)
    try:
        by_track = _calibrate_once(rec, unknowns, replace(params, heading_model="vo_track"), 0.0, readout)
    except CalibrationError as e:
        return by_yaw, "vo_yaw", f"the VO's yaw (its direction of travel is unusable: {e})"
    ya, sa = _main_lens_yaw(by_yaw)
    yb, sb = _main_lens_yaw(by_track)
    diff = math.degrees(yb - ya)
    if not sb > sa:
        return by_track, "vo_track", (f"the VO's direction of travel: it determines the boresight yaw better than the "
                                      f"VO's yaw (σ {math.degrees(sb):.3f}° against {math.degrees(sa):.3f}°)")
    spread = math.sqrt(sb * sb - sa * sa)
    stat = (yb - ya) ** 2 / (sb * sb - sa * sa)
    if stat > params.crab_test_chi2:
        return by_track, "vo_track", (
            f"the VO's direction of travel: the platform crabs (the boresight yaw against the VO's yaw and against "
            f"its direction of travel differ by {diff:+.3f}° ± {math.degrees(spread):.3f}°, χ² {stat:.1f} > "
            f"{params.crab_test_chi2:g})")
    return by_yaw, "vo_yaw", (
        f"the VO's yaw: no crab shows (the boresight yaw against its direction of travel differs by {diff:+.3f}° ± "
        f"{math.degrees(spread):.3f}°, χ² {stat:.1f} ≤ {params.crab_test_chi2:g}), and its σ is "
        f"{math.degrees(sa):.3f}° against {math.degrees(sb):.3f}°")


def _main_lens_yaw(cal: Calibration) -> Tuple[float, float]:
    """The yaw (rad) of the lens that saw the most markers (the boresight yaw ∓ half the lenses' relative rotation
    about z) and its σ: what the headings of the recording rest on."""
    k = int(np.argmax(cal.lens_observations))
    return float(cal.boresight_rpy[2] + (k - 0.5) * cal.lenses.lens_rotation[2]), float(cal.lens_yaw_sigma[k])


def _check_determined(cal: Calibration, unknowns: Unknowns, params: CalibrationParams) -> List[str]:
    """CalibrationError naming the parameters whose 1-σ exceeds its limit, why, and what to record or try. The
    boresight roll and pitch are not refused: when the platform turned too little to tell them from the
    odometry's own tilt they come with their (large) σ and a warning (returned): while processing, the
    markers correct the platform's tilt, so the heading does not rest on them."""
    sd = cal.boresight_sigma
    limit = math.radians(params.max_boresight_sigma_deg)
    warnings = []
    loose = [name for name, s in zip(("roll", "pitch"), sd[:2]) if not s <= limit]
    if loose:
        warnings.append(
            f"the boresight {' and '.join(loose)} (1-σ {', '.join(f'{math.degrees(s):.3f}°' for s in sd[:2])}) are "
            "not told apart from the odometry's own tilt: the platform turned too little; the markers correct the "
            "platform's tilt while processing, so the heading does not rest on them. To separate them, drive a "
            "loop or turns with markers in view (or, when the odometry is levelled by an IMU, give calibrate "
            "--params with 'calibration: {odom_levelled: true}')")
    # the yaw a marker's heading rests on is that of the lens that saw it: each lens that saw a fair share of the
    # markers must be determined; a lens that saw few is known as well as the lenses' prior allows (a warning)
    share = cal.lens_observations / max(int(cal.lens_observations.sum()), 1)
    seen = share >= _LENS_SHARE
    bad = ["yaw"] if not np.all(cal.lens_yaw_sigma[seen] <= limit) else []
    for name, k in (("front", 0), ("back", 1)):
        if not seen[k] and not cal.lens_yaw_sigma[k] <= limit:
            warnings.append(
                f"the {name} lens saw {int(cal.lens_observations[k])} of the {int(cal.lens_observations.sum())} "
                f"marker observations: its yaw is known to ± {math.degrees(cal.lens_yaw_sigma[k]):.3f}° only (the "
                f"other lens's to ± {math.degrees(cal.lens_yaw_sigma[1 - k]):.3f}°); markers it sees count for that "
                "much less while processing. To determine it, drive so that markers pass on both sides of the camera")
    advice = []
    if "yaw" in bad:
        other = "vo_track" if cal.heading_model == "vo_yaw" else "vo_yaw"
        advice.append(f"the yaw is told from the map→odom yaw by the prism track's direction while driving "
                      f"({cal.heading_model_reason}): drive longer straight stretches with markers in view at "
                      f"≥ {params.min_speed} m/s, or try `calibrate --heading-model {other}`")
    if unknowns.lever_arm:
        bad += [f"lever arm {name}" for name, s in zip("xyz", cal.lever_arm_sigma) if not s <= params.max_lever_sigma]
    if unknowns.time_offset and not cal.time_offset_sigma <= params.max_time_offset_sigma:
        bad.append("time offset")
    if unknowns.readout and not cal.readout_sigma <= params.max_readout_sigma:
        bad.append("readout time")
        advice.append("for the readout, turn in place (up to 60°/s) beside markers about 2 m away, some low and "
                      "some high (doc/field_guide.md, 'How to drive a calibration run')")
    rotation_limit = math.radians(params.max_lens_rotation_sigma_deg)
    if unknowns.lenses and not (cal.lens_offset_sigma <= params.max_lens_offset_sigma
                                and np.all(cal.lens_rotation_sigma <= rotation_limit)):
        warnings.append(
            f"the lenses are loosely determined (offset ± {1e3 * cal.lens_offset_sigma:.1f} mm, rotation ± "
            f"{', '.join(f'{math.degrees(s):.3f}' for s in cal.lens_rotation_sigma)}°; their prior "
            f"± {1e3 * params.lens_offset_prior:.0f} mm, ± {params.lens_rotation_prior_deg}°): their uncertainty is "
            "in the boresight's σ. They show in markers at several ranges (2-10 m) on both sides of the camera, "
            "near its seams (±90° from its front): turn in place beside markers about 2 m away, which shows each "
            "to both lenses (doc/field_guide.md, 'How to drive a calibration run'), or drive past markers on both "
            "sides; or give the camera's values (pipeline lens_offset) and calibrate --no-lenses")
    if not bad:
        return warnings
    advice += warnings
    values = (", ".join(f"{math.degrees(s):.3f}°" for s in sd)
              + (", lever arm " + ", ".join(f"{1e3 * s:.1f} mm" for s in cal.lever_arm_sigma)
                 if unknowns.lever_arm else "")
              + (f", time offset {1e3 * cal.time_offset_sigma:.1f} ms" if unknowns.time_offset else "")
              + (f", readout {1e3 * cal.readout_sigma:.1f} ms" if unknowns.readout else "")
              + (f", lens offset {1e3 * cal.lens_offset_sigma:.1f} mm, lens rotation "
                 f"{math.degrees(float(np.max(cal.lens_rotation_sigma))):.3f}°" if unknowns.lenses else ""))
    raise CalibrationError(
        "the recording does not determine the boresight " + ", ".join(bad) + f" (1-σ {values}; limits "
        f"{params.max_boresight_sigma_deg}°, {1e3 * params.max_lever_sigma:.0f} mm, "
        f"{1e3 * params.max_time_offset_sigma:.0f} ms, readout {1e3 * params.max_readout_sigma:.0f} ms, lens offset "
        f"{1e3 * params.max_lens_offset_sigma:.0f} mm, lens rotation {params.max_lens_rotation_sigma_deg}°): "
        + "; ".join(advice or ["record markers in more directions, at several ranges and elevations, while driving "
                               "and turning"]))


def _nominal_fit(pb, params: CalibrationParams, x0: np.ndarray):
    """(its layout, its parameters) of the fit "before": the nominal transform with the heading offsets δ fitted,
    started from δ constant, the robust mean of the heading constraints."""
    yh, sh = pb.yaw_head, pb.sigma_head
    sub = np.linspace(0, len(yh) - 1, min(len(yh), 2000)).astype(int)
    d0 = yaw_consensus(yh[sub], sh[sub], floor=math.radians(2.0))[0]
    nominal = _Layout(pb, (), nuisance=False)
    p = np.zeros(nominal.n + 1)
    p[nominal.o_d:nominal.o_t] = d0
    return nominal, _fit(pb, nominal, p, x0, params).p


def _used_and_skipped(setup, kept: np.ndarray):
    """(which observations the fit used (``kept``: their indices), the skipped ones by reason, the usable ones
    the fit's gate dropped counted as outliers)."""
    used = np.zeros(len(setup.usable), dtype=bool)
    used[kept] = True
    skipped = dict(setup.skipped)
    outliers = int(np.count_nonzero(setup.usable & ~used))
    if outliers:
        skipped["outlier (beyond the gate)"] = skipped.get("outlier (beyond the gate)", 0) + outliers
    return used, skipped


def _lens_yaw_sigma(C: np.ndarray, free, sd: np.ndarray) -> np.ndarray:
    """Each lens's yaw σ (front, back): the boresight yaw ∓ half the relative rotation about z, from the
    covariance ``C`` of the ``free`` unknowns (``sd``: the unknowns' σ; without the lenses the boresight's)."""
    lens_yaw_sigma = np.full(2, sd[2])
    if 2 in free and 11 in free:
        i, j = free.index(2), free.index(11)
        lens_yaw_sigma = np.sqrt(np.maximum([C[i, i] + C[j, j] / 4 + s * C[i, j] for s in (-1.0, 1.0)], 0.0))
    return lens_yaw_sigma


def _calibrate_once(rec: Recording, unknowns: Unknowns, params: CalibrationParams, time_shift: float,
                    readout: float) -> Calibration:
    """One linearised solve of :func:`calibrate` with the prism stamps moved by ``time_shift`` (s) and the
    observations at their row times with the rolling-shutter ``readout`` (s); σ not checked."""
    setup = setup_problem(rec, params, time_shift, readout)
    pb, idx = setup.problem, setup.index
    n = len(setup.usable)
    x0 = np.zeros(N_GLOBALS)
    nominal, before = _nominal_fit(pb, params, x0)
    d_b = nominal.unpack(before, x0)[1]
    pb.refine_heading(d_b)
    free = unknowns.free()
    lay = _Layout(pb, free)
    p = np.zeros(lay.n + 1)
    p[lay.o_d:lay.o_t] = d_b
    fit = _fit(pb, lay, p, x0, params)
    x, d, th, off = lay.unpack(fit.p, x0)
    sd_p = np.sqrt(np.maximum(np.diag(fit.cov), 0.0))
    sd = np.full(N_GLOBALS, np.nan)
    sd[list(free)] = sd_p[:lay.G]
    sd_p[lay.n] = 0.0                    # the sink: what is fixed
    tilt_sd = sd_p[lay.tilt[0]]
    off_sd = sd_p[lay.offsets]

    a_before = _angles(pb, nominal, before, x0)
    a_after = _angles(pb, lay, fit.p, x0)
    res_b = np.full(n, np.nan)
    res_a = np.full(n, np.nan)
    res_b[idx] = a_before
    res_a[idx] = a_after
    used, skipped = _used_and_skipped(setup, idx[fit.mask_o])
    mask_o, mask_h = fit.mask_o, fit.mask_h
    rh = pb.heading_residuals(x, d)[mask_h]
    lens_yaw_sigma = _lens_yaw_sigma(fit.cov, free, sd)
    front = pb.lenses_at(x).front_weight(pb.u[mask_o]) >= 0.5   # who saw what
    return Calibration(
        boresight_rpy=x[:3].copy(),
        boresight_sigma=sd[:3].copy(),
        lever_arm_delta=x[3:6].copy(),
        lever_arm_sigma=sd[3:6].copy(),
        lever_arm_estimated=bool(unknowns.lever_arm),
        cov=fit.cov[:lay.G, :lay.G].copy(),
        residual_rms_before=float(np.sqrt(np.mean(a_before[mask_o] ** 2))),
        residual_rms_after=float(np.sqrt(np.mean(a_after[mask_o] ** 2))),
        residual_median_before=float(np.median(a_before[mask_o])),
        residual_median_after=float(np.median(a_after[mask_o])),
        heading_rms=float(np.sqrt(np.mean(rh ** 2))) if len(rh) else float("nan"),
        variance_factors=fit.variance_factors,
        n_observations=n,
        n_used=int(used.sum()),
        n_markers=len({int(i) for i in setup.ids[used]}),
        n_heading=int(mask_h.sum()),
        moving_time=float(mask_h.sum() * params.heading_step),
        iterations=fit.iterations,
        used=used,
        residuals_before=res_b,
        residuals_after=res_a,
        skipped=skipped,
        time_offset_delta=float(x[6]),
        time_offset_sigma=float(sd[6]),
        time_offset_estimated=bool(unknowns.time_offset),
        readout=float(x[7]),
        readout_sigma=float(sd[7]),
        readout_estimated=bool(unknowns.readout),
        lenses=pb.lenses_at(x),
        lens_offset_sigma=float(sd[8]),
        lens_rotation_sigma=sd[9:12].copy(),
        lenses_estimated=bool(unknowns.lenses),
        lens_yaw_sigma=lens_yaw_sigma,
        lens_observations=np.array([int(front.sum()), int((~front).sum())]),
        odom_tilt=th[0].copy(),
        odom_tilt_sigma=tilt_sd.copy(),
        heading_model=params.heading_model,
        marker_offsets={int(m): (off[k].copy(), off_sd[k].copy()) for k, m in enumerate(pb.markers.ids)},
    )
