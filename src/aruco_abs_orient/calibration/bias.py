"""The markers' pattern bias in the calibration's σ: an error of a marker's centre that its pattern sets, the same
on every frame, so it does not average out over a recording.

In: each observation's cell width in image pixels and the image's pixel pitch; the estimator's normal matrix,
local Jacobians, weights and residual geometry. Out: :func:`pattern_bias_sigma`, the bias's 1-σ per axis of each
observation (rad): ``pattern_bias_px · (pattern_bias_cell_px / cell)³`` pixels, the cell no narrower than 1.7 px
(bench/detection.py ``pattern_bias``: rendered markers of every id, their mean centre error against the rendered
truth); and
:func:`pattern_bias_covariance`, what these biases add to the covariance of the estimate (a consider parameter:
each marker's bias a 2-D random constant along the azimuth and the elevation of its bearing, scaled by each
observation's σ, with the estimate's sensitivity K = H⁻¹ Jᵀ W to it). The estimate itself does not change.
"""

from __future__ import annotations

import numpy as np

from .model import CalibrationParams

__all__ = ["pattern_bias_sigma", "pattern_bias_covariance"]

_SATURATED_CELL_PX = 1.7    # below it the bias stops growing (0.10-0.12 px down to 1.4 px, where few are read)


def pattern_bias_sigma(params: CalibrationParams, pitch: float, cell_px: np.ndarray) -> np.ndarray:
    """1-σ (rad) per axis of the pattern bias of observations whose cells are ``cell_px`` (N,) pixels wide in an
    image of ``pitch`` rad per pixel."""
    cell = np.maximum(np.asarray(cell_px, dtype=float), _SATURATED_CELL_PX)
    return pitch * params.pattern_bias_px * (params.pattern_bias_cell_px / cell) ** 3


def _tangents(u: np.ndarray):
    """Unit directions of increasing azimuth and elevation (N, 3) at the bearings ``u`` (N, 3) (camera z up; the
    camera's x axis stands in for the azimuth's direction at a pole)."""
    east = np.cross([0.0, 0.0, 1.0], u)
    norm = np.linalg.norm(east, axis=1)
    east[norm < 1e-9] = [0.0, 1.0, 0.0]
    east /= np.maximum(np.linalg.norm(east, axis=1), 1e-12)[:, None]
    return east, np.cross(u, east)


def pattern_bias_covariance(H: np.ndarray, J: np.ndarray, idx: np.ndarray, w: np.ndarray, u: np.ndarray,
                            predicted: np.ndarray, bias: np.ndarray, marker: np.ndarray, sink: int) -> np.ndarray:
    """The covariance (n, n) of the parameters that the markers' pattern biases add: ``H`` (n, n) the normal
    matrix the estimate was solved with, ``J`` (N, 3, s) the residuals' local Jacobians in the parameters
    ``idx`` (N, s), ``w`` (N,) their weights, ``u`` and ``predicted`` (N, 3) the observed and predicted bearings
    (residual u × predicted), ``bias`` (N,) rad the bias's 1-σ per axis, ``marker`` (N,) each observation's
    marker (0 … Nm − 1), ``sink`` the index of the fixed parameters (kept 0)."""
    n, nm = H.shape[0], int(marker.max()) + 1 if len(marker) else 0
    if nm == 0 or not np.any(bias > 0):
        return np.zeros_like(H)
    Jw = J * w[:, None, None]
    G = np.zeros((n, 2 * nm))
    for k, direction in enumerate(_tangents(u)):
        dr = bias[:, None] * np.cross(direction, predicted)          # the residual moved by a unit bias
        np.add.at(G, (idx.ravel(), np.repeat(2 * marker + k, idx.shape[1])), np.einsum("nka,nk->na", Jw, dr).ravel())
    G[sink] = 0.0
    S = np.linalg.solve(H, G)
    return S @ S.T
