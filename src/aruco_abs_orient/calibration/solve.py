"""Solving the calibration problem: robust weighted least squares, σ, and the entry point.

In: the observations of a recording (a :class:`~.model.Recording`),
which unknowns to free (:class:`~.model.Unknowns`) and :class:`~.model.CalibrationParams`. Out: a
:class:`~.model.Calibration` (boresight, lever arm, time offset with their covariance, residuals,
counts), or :class:`~.model.CalibrationError` saying why the recording cannot determine it.

Gauss-Newton over the globals x = (roll, pitch, yaw, Δl, Δτ) and the knots of δ(t) (``problem``):
a Cauchy-weighted robust stage, a gate at ``outlier_gate`` σ, then least squares with the variance
factors of the marker bearings and of the track headings estimated (variance component estimation),
so the σ reported reflect the actual scatter. Δτ is linearised: :func:`calibrate` moves the prism clock
by the Δτ found and solves again until it is ≪ 1 ms.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Dict, NamedTuple, Optional, Tuple

import numpy as np

from ..solver import yaw_consensus
from .model import N_GLOBALS, Calibration, CalibrationError, CalibrationParams, Recording, Unknowns
from .problem import Problem, setup_problem

__all__ = ["calibrate"]


def _cauchy(e: np.ndarray, k: float) -> np.ndarray:
    return 1.0 / (1.0 + (e / k) ** 2)


class _Solution:
    """Globals x (N_GLOBALS,) = (roll, pitch, yaw, Δl (3), Δτ, Δρ) and the knot values d of δ(t)."""

    def __init__(self, x, d):
        self.x, self.d = x, d


class _Weights(NamedTuple):
    """How :func:`_solve` weights the two groups: ``mask_o``/``mask_h`` (0/1 per marker observation /
    heading constraint), ``robust`` (Cauchy IRLS on top), ``scale_o``/``scale_h`` (multiply the a-priori σ)."""

    mask_o: np.ndarray
    mask_h: np.ndarray
    robust: bool
    scale_o: float
    scale_h: float


class _Fit(NamedTuple):
    """:func:`_fit`'s result: the solution, the covariance of (free globals, knots), the observations
    and heading constraints kept, the variance factors of the groups and the iterations."""

    sol: _Solution
    Hinv: np.ndarray
    mask_o: np.ndarray
    mask_h: np.ndarray
    variance_factors: Dict[str, float]
    iterations: int


def _solve(pb: Problem, sol: _Solution, free: Tuple[int, ...], weights: _Weights,
           params: CalibrationParams) -> Tuple[_Solution, np.ndarray, int]:
    """Gauss-Newton over the globals ``free`` (indices into x; () for the knots only) and the knots.

    Returns the solution, the inverse normal matrix (covariance of the free globals then the knots,
    σ scaled as ``weights`` says) and the iterations."""
    mask_o, mask_h, robust, scale_o, scale_h = weights
    K = len(pb.knots)
    n_glob = len(free)
    n = n_glob + K
    x, d = sol.x.copy(), sol.d.copy()
    h = 1e-6
    Hinv = np.zeros((n, n))
    iterations = 0
    for iterations in range(1, params.max_iterations + 1):  # noqa: B007  (reported)
        delta = pb.delta_at(d, pb.i_obs, pb.a_obs)
        r = pb.residuals(x, delta)                                        # (N, 3)
        sig = pb.sigma * scale_o
        e = np.linalg.norm(r, axis=1) / sig
        rh = pb.heading_residuals(x, d)
        sigh = pb.sigma_head * scale_h
        eh = np.abs(rh) / sigh
        w = mask_o / sig ** 2
        wh = mask_h / sigh ** 2
        if robust:
            k_o = max(params.loss_scale, 2.0 * float(np.median(e[mask_o > 0]))) if np.any(mask_o > 0) else 1.0
            k_h = max(params.loss_scale, 2.0 * float(np.median(eh[mask_h > 0]))) if np.any(mask_h > 0) else 1.0
            w = w * _cauchy(e, k_o)
            wh = wh * _cauchy(eh, k_h)
        # Jacobians: globals and δ by central differences (the model is cheap and vectorised)
        Jg = np.empty(r.shape + (n_glob,))
        for j, g in enumerate(free):
            step = np.zeros(len(x))
            step[g] = h
            Jg[:, :, j] = (pb.residuals(x + step, delta) - pb.residuals(x - step, delta)) / (2 * h)
        c = (pb.residuals(x, delta + h) - pb.residuals(x, delta - h)) / (2 * h)   # ∂r/∂δ
        i, a = pb.i_obs, pb.a_obs
        H = np.zeros((n, n))
        gvec = np.zeros(n)
        H[:n_glob, :n_glob] = np.einsum("n,nki,nkj->ij", w, Jg, Jg)
        gvec[:n_glob] = np.einsum("n,nki,nk->i", w, Jg, r)
        cc = w * np.sum(c * c, axis=1)
        cr = w * np.sum(c * r, axis=1)
        Jc = np.einsum("n,nki,nk->ni", w, Jg, c)                          # (N, G)
        for wi, idx in (((1.0 - a), i), (a, i + 1)):
            gvec[n_glob:] += np.bincount(idx, cr * wi, minlength=K)
            for j in range(n_glob):
                col = np.bincount(idx, Jc[:, j] * wi, minlength=K)
                H[j, n_glob:] += col
                H[n_glob:, j] += col
        for wa, wb, ia, ib in (((1 - a), (1 - a), i, i), ((1 - a), a, i, i + 1), (a, (1 - a), i + 1, i),
                               (a, a, i + 1, i + 1)):
            np.add.at(H, (n_glob + ia, n_glob + ib), cc * wa * wb)
        ih, ah = pb.i_head, pb.a_head
        for wa, ia in (((1 - ah), ih), (ah, ih + 1)):
            gvec[n_glob:] += np.bincount(ia, wh * rh * wa, minlength=K)
            for wb, ib in (((1 - ah), ih), (ah, ih + 1)):
                np.add.at(H, (n_glob + ia, n_glob + ib), wh * wa * wb)
        if 6 in free:  # the heading residuals depend on Δτ too (∂/∂Δτ = turn rate)
            jt = free.index(6)
            H[jt, jt] += np.sum(wh * pb.rate_head ** 2)
            gvec[jt] += np.sum(wh * pb.rate_head * rh)
            for wa, ia in (((1 - ah), ih), (ah, ih + 1)):
                col = np.bincount(ia, wh * pb.rate_head * wa, minlength=K)
                H[jt, n_glob:] += col
                H[n_glob:, jt] += col
        # the odometry's tilt knots (the first one is 0: its tilt drift since the recording's start): each tied
        # to 0, adjacent ones to each other (random walk, the second knot to the first's 0)
        tilt = [free.index(g) for g in pb.tilt_indices() if g in free]
        if tilt:
            tj = np.array(tilt)
            w0, w1 = 1.0 / pb.tilt_sigma ** 2, 1.0 / pb.tilt_drift_sigma ** 2
            H[tj, tj] += w0
            gvec[tj] += w0 * x[list(pb.tilt_indices())]
            H[tj[:2], tj[:2]] += w1
            gvec[tj[:2]] += w1 * x[list(pb.tilt_indices()[:2])]
            for a_, b_ in zip(tj[:-2], tj[2:]):   # same axis, next knot
                diff = x[free[b_]] - x[free[a_]]
                H[a_, a_] += w1
                H[b_, b_] += w1
                H[a_, b_] -= w1
                H[b_, a_] -= w1
                gvec[a_] -= w1 * diff
                gvec[b_] += w1 * diff
        # random-walk prior between adjacent knots
        wp = 1.0 / pb.drift_sigma ** 2
        dd = np.diff(d)
        kk = np.arange(K - 1) + n_glob
        np.add.at(H, (kk, kk), wp)
        np.add.at(H, (kk + 1, kk + 1), wp)
        np.add.at(H, (kk, kk + 1), -wp)
        np.add.at(H, (kk + 1, kk), -wp)
        gvec[n_glob:-1] -= wp * dd
        gvec[n_glob + 1:] += wp * dd
        try:
            Hinv = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            raise CalibrationError("the normal equations are singular: the recording does not determine "
                                   "the calibration (too few markers or no motion)") from None
        if not np.all(np.isfinite(Hinv)):
            raise CalibrationError("the normal equations are singular: the recording does not determine "
                                   "the calibration (too few markers or no motion)")
        dx = -Hinv @ gvec
        x[list(free)] += dx[:n_glob]
        d = d + dx[n_glob:]
        if float(np.max(np.abs(dx))) < 1e-10:
            break
    return _Solution(x, d), Hinv, iterations


def _angles(pb: Problem, sol: _Solution) -> np.ndarray:
    """Angle (rad) between observed and predicted bearings."""
    delta = pb.delta_at(sol.d, pb.i_obs, pb.a_obs)
    r = pb.residuals(sol.x, delta)
    dot = np.sum(pb.u * pb.predict(sol.x, delta), axis=1)
    return np.arctan2(np.linalg.norm(r, axis=1), dot)


def _fit(pb: Problem, sol: _Solution, free: Tuple[int, ...], params: CalibrationParams) -> _Fit:
    """Robust stage, gate, least squares with variance component estimation."""
    n_o, n_h = len(pb.u), len(pb.yaw_head)
    mask_o, mask_h = np.ones(n_o), np.ones(n_h)
    sol, _, it = _solve(pb, sol, free, _Weights(mask_o, mask_h, True, 1.0, 1.0), params)
    scale_o = scale_h = 1.0
    vf = {"markers": float("nan"), "heading": float("nan")}
    Hinv = None
    for _ in range(4):
        delta = pb.delta_at(sol.d, pb.i_obs, pb.a_obs)
        e = np.linalg.norm(pb.residuals(sol.x, delta), axis=1) / (pb.sigma * scale_o)
        eh = np.abs(pb.heading_residuals(sol.x, sol.d)) / (pb.sigma_head * scale_h)
        # a 2-D residual: gate on its norm; heading: on its absolute value
        mask_o = (e <= params.outlier_gate).astype(float)
        mask_h = (eh <= params.outlier_gate).astype(float)
        sol, Hinv, it2 = _solve(pb, sol, free, _Weights(mask_o, mask_h, False, scale_o, scale_h), params)
        it += it2
        delta = pb.delta_at(sol.d, pb.i_obs, pb.a_obs)
        e = np.linalg.norm(pb.residuals(sol.x, delta), axis=1) / (pb.sigma * scale_o)
        eh = np.abs(pb.heading_residuals(sol.x, sol.d)) / (pb.sigma_head * scale_h)
        f_o = float(np.sum(mask_o * e ** 2) / max(2.0 * mask_o.sum(), 1.0))
        f_h = float(np.sum(mask_h * eh ** 2) / max(mask_h.sum(), 1.0)) if n_h else 1.0
        vf = {"markers": f_o * scale_o ** 2, "heading": f_h * scale_h ** 2 if n_h else float("nan")}
        done = abs(f_o - 1.0) < 0.05 and abs(f_h - 1.0) < 0.05
        scale_o *= math.sqrt(max(f_o, 1e-6))
        scale_h *= math.sqrt(max(f_h, 1e-6))
        if done:
            break
    # the residuals are correlated in time (the VO's yaw walk between knots, the smoothed track heading, a
    # platform that wanders): n correlated residuals weigh like n / c independent ones. The covariance is
    # taken with each group's σ inflated by √c, c from the residuals' own autocorrelation, so it stays
    # honest; the estimate keeps the weights above (re-weighting the groups by c made it worse on the
    # bench: markers seen together in one frame correlate more than the track headings).
    delta = pb.delta_at(sol.d, pb.i_obs, pb.a_obs)
    order = np.argsort(pb.t, kind="stable")
    r_o = pb.residuals(sol.x, delta)[order][mask_o[order] > 0] / pb.sigma[order][mask_o[order] > 0, None]
    c_o = correlation_factor(r_o)
    c_h = correlation_factor((pb.heading_residuals(sol.x, sol.d) / pb.sigma_head)[mask_h > 0, None]) if n_h else 1.0
    vf.update({"markers_correlation": c_o, "heading_correlation": c_h})
    if c_o > 1.0 or c_h > 1.0:
        weights = _Weights(mask_o, mask_h, False, scale_o * math.sqrt(c_o), scale_h * math.sqrt(c_h))
        Hinv = _solve(pb, sol, free, weights, replace(params, max_iterations=1))[1]
    return _Fit(sol, Hinv, mask_o.astype(bool), mask_h.astype(bool), vf, it)


def correlation_factor(series: np.ndarray, max_lag: int = 200) -> float:
    """Variance inflation 1 + 2 Σ ρ_k (≥ 1) of the mean of a time-ordered series (n, c) of residuals: ρ_k
    its lag-k autocorrelation (the columns pooled), summed while positive (the initial positive sequence),
    up to ``max_lag`` or n/10 lags."""
    x = np.asarray(series, dtype=float)
    n = len(x)
    if n < 20:
        return 1.0
    x = x - x.mean(axis=0)
    var = float(np.sum(x * x))
    if var <= 0.0:
        return 1.0
    total = 0.0
    for k in range(1, min(max_lag, n // 10) + 1):
        rho = float(np.sum(x[k:] * x[:-k])) / var
        if rho <= 0.0:
            break
        total += rho
    return 1.0 + 2.0 * total


def calibrate(rec: Recording, unknowns: Optional[Unknowns] = None, params: Optional[CalibrationParams] = None,
              readout: float = 0.0) -> Calibration:
    """Boresight (and optionally lever arm, time offset, readout) of the camera from all marker observations
    of a recording.

    Args:
        rec: the observations, odometry, prism track, marker map and nominal lever arms, on one clock
            (:class:`~.model.Recording`; ids not in the map and observations without a prism position are
            skipped and counted).
        unknowns: which parameters beside the boresight are freed (:class:`~.model.Unknowns`, default none):
            ``lever_arm`` the camera origin in base_link (3 more unknowns); ``time_offset`` the residual time
            offset Δτ (s) of the prism stamps given (one more unknown; linearised, so the offset given should
            be within ~0.1 s, as ``timesync.estimate_offset`` gives it); ``readout`` the rolling-shutter
            readout time, starting from ``readout`` (needs turns with markers above and below the horizon).
        params: :class:`CalibrationParams`.
        readout: the camera's rolling-shutter readout time (s; 0 = global shutter), fixed or the start of its
            estimate: an observation is captured at ``obs_times + obs_rows · readout``.

    Raises:
        CalibrationError: malformed inputs, or a recording that cannot determine the calibration (no
            markers, too few observations, no driving for the boresight yaw, parameters whose σ exceed
            the limits) — the message says which and why.
    """
    if not (math.isfinite(readout) and 0.0 <= readout < 1.0):
        raise CalibrationError(f"readout: expected seconds in [0, 1), got {readout!r}")
    unknowns = unknowns or Unknowns()
    params = params or CalibrationParams()
    params.validate()
    cal = _calibrate_once(rec, unknowns, params, 0.0, readout)
    shift, readout = cal.time_offset_delta, readout + cal.readout
    for _ in range(4):  # Δτ, Δρ are linearised: move the clocks by them and solve again until they are ≪ 1 ms
        if abs(cal.time_offset_delta) < 2e-4 and abs(cal.readout) < 2e-4:
            break
        cal = _calibrate_once(rec, unknowns, params, shift, readout)
        shift += cal.time_offset_delta
        readout += cal.readout
    cal.time_offset_delta, cal.readout = shift, readout
    return cal


def _check_determined(sd: np.ndarray, unknowns: Unknowns, params: CalibrationParams) -> None:
    """CalibrationError naming the parameters whose 1-σ ``sd`` (N_GLOBALS,) exceeds its limit."""
    bad = [name for name, s in zip(("roll", "pitch", "yaw"), sd[:3])
           if not s <= math.radians(params.max_boresight_sigma_deg)]
    if unknowns.lever_arm:
        bad += [f"lever arm {name}" for name, s in zip("xyz", sd[3:6]) if not s <= params.max_lever_sigma]
    if unknowns.time_offset and not sd[6] <= params.max_time_offset_sigma:
        bad.append("time offset")
    if unknowns.readout and not sd[7] <= params.max_readout_sigma:
        bad.append("readout time")
    if bad:
        raise CalibrationError(
            "the recording does not determine the boresight " + ", ".join(bad) + " (1-σ "
            + ", ".join(f"{math.degrees(s):.3f}°" for s in sd[:3])
            + (", " + ", ".join(f"{1e3 * s:.1f} mm" for s in sd[3:6]) if unknowns.lever_arm else "")
            + (f", {1e3 * sd[6]:.1f} ms" if unknowns.time_offset else "")
            + (f", readout {1e3 * sd[7]:.1f} ms" if unknowns.readout else "")
            + f"; limits {params.max_boresight_sigma_deg}°, {1e3 * params.max_lever_sigma:.0f} mm, "
            f"{1e3 * params.max_time_offset_sigma:.0f} ms and readout {1e3 * params.max_readout_sigma:.0f} ms): "
            "record markers in more directions, at several ranges and elevations, while driving and turning"
            + ("; for the readout, turn in place (up to 60°/s) beside markers about 2 m away, some low and some "
               "high (doc/field_guide.md, 'How to drive a calibration run')" if "readout time" in bad else ""))


def _calibrate_once(rec: Recording, unknowns: Unknowns, params: CalibrationParams, time_shift: float,
                    readout: float) -> Calibration:
    """One linearised solve of :func:`calibrate` with the prism stamps moved by ``time_shift`` (s) and the
    observations at their row times with the rolling-shutter ``readout`` (s)."""
    setup = setup_problem(rec, params, time_shift, readout)
    pb, idx = setup.problem, setup.index
    n = len(setup.usable)
    # start: δ constant, the robust mean of the heading constraints
    yh, sh = pb.yaw_head, pb.sigma_head
    sub = np.linspace(0, len(yh) - 1, min(len(yh), 2000)).astype(int)
    d0 = yaw_consensus(yh[sub], sh[sub], floor=math.radians(2.0))[0]
    start = _Solution(np.zeros(pb.n_x), np.full(len(pb.knots), d0))
    # before: the nominal transform, δ(t) fitted
    before = _fit(pb, start, (), params).sol
    pb.refine_heading(before.d)
    free = unknowns.free()
    fit = _fit(pb, before, free + pb.tilt_indices(), params)
    sol = fit.sol

    cov = fit.Hinv[:len(free), :len(free)]
    sd = np.full(N_GLOBALS, np.nan)
    sd[list(free)] = np.sqrt(np.maximum(np.diag(cov), 0.0))
    _check_determined(sd, unknowns, params)

    a_before = _angles(pb, before)
    a_after = _angles(pb, sol)
    res_b = np.full(n, np.nan)
    res_a = np.full(n, np.nan)
    res_b[idx] = a_before
    res_a[idx] = a_after
    used = np.zeros(n, dtype=bool)
    used[idx[fit.mask_o]] = True
    skipped = dict(setup.skipped)
    outliers = int(np.count_nonzero(setup.usable & ~used))
    if outliers:
        skipped["outlier (beyond the gate)"] = skipped.get("outlier (beyond the gate)", 0) + outliers
    mask_o, mask_h = fit.mask_o, fit.mask_h
    rh = pb.heading_residuals(sol.x, sol.d)[mask_h]
    return Calibration(
        boresight_rpy=sol.x[:3].copy(),
        boresight_sigma=sd[:3].copy(),
        lever_arm_delta=sol.x[3:6].copy(),
        lever_arm_sigma=sd[3:6].copy(),
        lever_arm_estimated=bool(unknowns.lever_arm),
        cov=cov.copy(),
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
        time_offset_delta=float(sol.x[6]),
        time_offset_sigma=float(sd[6]),
        time_offset_estimated=bool(unknowns.time_offset),
        readout=float(sol.x[7]),
        readout_sigma=float(sd[7]),
        readout_estimated=bool(unknowns.readout),
    )
