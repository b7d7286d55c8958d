"""Time offset between the camera/VO clock and the total-station clock (DESIGN §4.7).

Sign convention, used everywhere in this module and by its callers:

    camera stamp = total-station (true) time + τ          (τ in seconds)

so a VO sample stamped ``t`` was taken at total-station time ``t − τ``; to put camera stamps on
the total station's clock, subtract τ (``OnlineOffsetEstimator.correct_stamp``). A camera that
lags the total station (the paper's 11 frames) has τ > 0.

Method: the prism track gives the direction of travel (the heading of the velocity vector, from a
zero-lag local quadratic fit of the prism positions), the VO gives a yaw with an unknown constant
offset and a slow drift. For a candidate τ the residual phases ``ψ_vo(t_k) − ψ_track(t_k − τ)``
are constant at the true τ except for noise and the drift; the estimate maximises the weighted
phase coherence

    C(τ) = Σ_windows |Σ_k w_k exp(i(ψ_vo(t_k) − ψ_track(t_k − τ) − d_j (t_k − t̄_j)))| / Σ_k w_k

where each window j (default: 60 s) gets its own constant phase (the unknown yaw offset, taken
care of by the modulus) and its own linear drift ``d_j`` (rad/s, fitted, bounded by
``max_drift``). The weights are the VO weights times the squared platform speed (zero below
``min_speed``), so standstill and crawling, where the track heading is noise, do not count. A
coarse grid over the search interval finds the peak, a golden-section search refines it to well
under a frame; the track heading is interpolated continuously on the unit circle (through the
velocity vector), so the curve is smooth in τ. The smoothing's own heading bias
σ²(v'ψ'/v + ψ''/2), which is not time-symmetric where the platform brakes or accelerates in a turn,
is removed before the search. ``sigma`` comes from the linearised least-squares equivalent of the
maximisation with a Newey-West sum over the track noise's correlation time.

The paper's method (normalised cross-correlation of unwrapped headings at whole-frame lags) is
``cross_correlation_offset``, kept as the baseline. Numbers that cannot be estimated raise
``TimeSyncError`` saying why. Python 3.8 compatible; numpy only.

The package, one module per stage (each says what goes in and what comes out):

- :mod:`.estimate`: :class:`OffsetEstimate` (what every estimator returns) and :class:`TimeSyncError`;
- :mod:`.heading`: the prism track's direction of travel (:func:`heading_from_track`);
- :mod:`.coherence`: the phase-coherence estimate (:func:`estimate_offset`,
  :func:`estimate_offset_from_marker_yaws`);
- :mod:`.baseline`: the paper's cross-correlation (:func:`cross_correlation_offset`);
- :mod:`.online`: the live node's incremental estimator (:class:`OnlineOffsetEstimator`).
"""

from .baseline import cross_correlation_offset
from .coherence import estimate_offset, estimate_offset_from_marker_yaws
from .estimate import OffsetEstimate, TimeSyncError
from .heading import TrackHeading, heading_from_track
from .online import OnlineOffsetEstimator

__all__ = [
    "TimeSyncError",
    "TrackHeading",
    "OffsetEstimate",
    "heading_from_track",
    "estimate_offset",
    "estimate_offset_from_marker_yaws",
    "cross_correlation_offset",
    "OnlineOffsetEstimator",
]
