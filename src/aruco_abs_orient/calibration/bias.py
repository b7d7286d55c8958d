"""The markers' pattern bias in the calibration's σ: an error of a marker's centre that its pattern sets, the same
on every frame, so it does not average out over a recording.

In: each observation's cell widths along the image's azimuth and elevation (px; :func:`marker_cell_widths` from
its corners) and the image's pixel pitch; the estimator's normal matrix, local Jacobians, weights and residual
geometry. Out: :func:`pattern_bias_sigma`, the bias's 1-σ along the azimuth and the elevation of each observation
(rad): ``pattern_bias_px · (pattern_bias_cell_px / n)³ · (c / n)^1.5`` pixels along an axis whose cells are ``c``
wide, ``n`` the narrower of the two widths (no narrower than 1.7 px in the first factor): a marker seen obliquely,
its cells narrowed across, is biased along its long edges (bench/detection.py ``pattern_bias``: rendered markers
of every id, facing the camera and turned away from it, their mean centre error against the rendered truth); and
:func:`pattern_bias_covariance`, what these biases add to the covariance of the estimate (a consider parameter:
each marker's bias a 2-D random constant along the azimuth and the elevation of its bearing, scaled by each
observation's σ, with the estimate's sensitivity K = H⁻¹ Jᵀ W to it). The estimate itself does not change.
Upright markers (on walls and pillars) have their edges along the azimuth and the elevation; for others the
widths are those of their extent along the two directions.
"""

from __future__ import annotations

import numpy as np

from .model import CalibrationParams

__all__ = ["marker_cell_widths", "pattern_bias_sigma", "pattern_bias_covariance"]

_SATURATED_CELL_PX = 1.7    # below it the bias stops growing (0.10-0.12 px down to 1.4 px, where few are read)


def pattern_bias_sigma(params: CalibrationParams, pitch: float, cell_px: np.ndarray) -> np.ndarray:
    """1-σ (rad, (N, 2)) along the azimuth and the elevation of the pattern bias of observations whose cells are
    ``cell_px`` pixels wide along them ((N, 2); (N,): as wide along both) in an image of ``pitch`` rad per
    pixel."""
    cell = np.asarray(cell_px, dtype=float)
    cell = np.stack([cell, cell], axis=-1) if cell.ndim == 1 else cell
    narrow = np.min(cell, axis=-1, keepdims=True)
    base = pitch * params.pattern_bias_px * (params.pattern_bias_cell_px / np.maximum(narrow, _SATURATED_CELL_PX)) ** 3
    return base * (cell / narrow) ** 1.5


def marker_cell_widths(centres: np.ndarray, corners: np.ndarray, cells_across: int) -> np.ndarray:
    """The angular widths (rad, (N, 2)) along the azimuth and the elevation of the cells of markers seen at
    ``centres`` (N, 3) with ``corners`` (N, 4, 3) (bearings, in cyclic order) that are ``cells_across`` cells
    wide: of each edge pair's mean, the root sum of squares of its components along the direction (a square
    facing the camera gives its side whatever its roll)."""
    u = np.asarray(centres, dtype=float)
    c = np.asarray(corners, dtype=float)
    edges = np.stack([(c[:, 1] - c[:, 0] + c[:, 2] - c[:, 3]) / 2, (c[:, 3] - c[:, 0] + c[:, 2] - c[:, 1]) / 2], 1)
    widths = [np.sqrt(np.sum(np.einsum("nea,na->ne", edges, d) ** 2, axis=1)) for d in _tangents(u)]
    return np.stack(widths, axis=1) / cells_across


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
    (residual u × predicted), ``bias`` (N, 2) rad the bias's 1-σ along the azimuth and the elevation, ``marker``
    (N,) each observation's marker (0 … Nm − 1), ``sink`` the index of the fixed parameters (kept 0)."""
    n, nm = H.shape[0], int(marker.max()) + 1 if len(marker) else 0
    if nm == 0 or not np.any(bias > 0):
        return np.zeros_like(H)
    Jw = J * w[:, None, None]
    G = np.zeros((n, 2 * nm))
    for k, direction in enumerate(_tangents(u)):
        dr = bias[:, k, None] * np.cross(direction, predicted)          # the residual moved by a unit bias
        np.add.at(G, (idx.ravel(), np.repeat(2 * marker + k, idx.shape[1])), np.einsum("nka,nk->na", Jw, dr).ravel())
    G[sink] = 0.0
    S = np.linalg.solve(H, G)
    return S @ S.T
