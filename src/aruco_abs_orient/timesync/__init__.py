"""Time offset between the camera/VO clock and the total-station clock (doc/design.md §10).

Sign convention, used everywhere in this package and by its callers:

    camera stamp = total-station (true) time + τ          (τ in seconds)

so a VO sample stamped ``t`` was taken at total-station time ``t − τ``; to put camera stamps on
the total station's clock, subtract τ (``OnlineOffsetEstimator.correct_stamp``). A camera that
lags the total station (the paper's 11 frames) has τ > 0.

Method: the VO yaw (and the marker yaws) against the direction of travel of the prism track,
compared by phase coherence over candidate offsets (:mod:`.coherence` describes it).

The paper's method (normalised cross-correlation of unwrapped headings at whole-frame lags) is
``cross_correlation_offset``, kept as the baseline. Numbers that cannot be estimated raise
``TimeSyncError`` saying why. Python 3.8 compatible; numpy only.

The package, one module per stage (each says what goes in and what comes out):

- :mod:`.estimate`: :class:`OffsetEstimate` (what every estimator returns) and :class:`TimeSyncError`;
- :mod:`.heading`: the prism track's direction of travel (:func:`heading_from_track`);
- :mod:`.coherence`: the phase-coherence estimate (:func:`estimate_offset`,
  :func:`estimate_offset_from_marker_yaws`) and its knobs :class:`TimeSyncParams`;
- :mod:`.baseline`: the paper's cross-correlation (:func:`cross_correlation_offset`);
- :mod:`.online`: the live node's incremental estimator (:class:`OnlineOffsetEstimator`).
"""

from .baseline import cross_correlation_offset
from .coherence import TimeSyncParams, YawSeries, estimate_offset, estimate_offset_from_marker_yaws
from .estimate import OffsetEstimate, TimeSyncError
from .heading import TrackHeading, heading_from_track
from .online import OnlineOffsetEstimator

__all__ = [
    "TimeSyncError",
    "TimeSyncParams",
    "YawSeries",
    "TrackHeading",
    "OffsetEstimate",
    "heading_from_track",
    "estimate_offset",
    "estimate_offset_from_marker_yaws",
    "cross_correlation_offset",
    "OnlineOffsetEstimator",
]
