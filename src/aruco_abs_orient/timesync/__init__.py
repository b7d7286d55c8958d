"""Time offset between the camera/VO clock and the total-station clock (doc/design.md §10).

Sign convention, used everywhere in this package and by its callers (doc/design.md §2):

    camera stamp = total-station (true) time + τ          (τ in seconds)

A camera that lags the total station (the paper's 11 frames) has τ > 0; subtract τ to put camera stamps on
the total station's clock (``OnlineOffsetEstimator.correct_stamp``). What cannot be estimated raises
``TimeSyncError`` saying why. One module per stage: :mod:`.estimate` (the result and the error),
:mod:`.heading` (the prism track's direction of travel), :mod:`.coherence` (this package's estimate and
:class:`TimeSyncParams`), :mod:`.baseline` (the paper's cross-correlation), :mod:`.online` (the live node's).
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
