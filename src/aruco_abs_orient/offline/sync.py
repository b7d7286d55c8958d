"""``aruco-abs-orient timesync``: the camera/VO ↔ total-station time offset of a recording.

Uses the odometry yaw (``odom → base_link`` on /tf, camera clock) and the prism track (total-station
clock) of a bag: the phase-coherence estimate of :mod:`aruco_abs_orient.timesync` (DESIGN §4.7,
invariant to the unknown yaw offset), with the paper's cross-correlation printed beside it.
"""

from __future__ import annotations

import os
from typing import Dict, Optional, Tuple

from .. import timesync
from ..transforms import yaw_of
from .bagio import BagData, BagTopics, read_bag_data

__all__ = ["estimate_bag_offset"]


def estimate_bag_offset(bag: str, topics: Optional[BagTopics] = None, search: Tuple[float, float] = (-1.0, 1.0),
                        data: Optional[BagData] = None, plot_dir: Optional[str] = None) -> Dict[str, object]:
    """``{"timesync": OffsetEstimate, "timesync_baseline": OffsetEstimate or reason}`` of a bag.

    Offsets in seconds, camera stamps = total-station time + offset. Raises
    ``timesync.TimeSyncError`` when the recording cannot determine it (no motion, too short).
    """
    data = data or read_bag_data(bag, topics)
    if len(data.prism_stamps) < 2:
        raise timesync.TimeSyncError(f"{bag}: no prism track: the time offset needs the total station's positions")
    t_vo, yaw_vo = data.odom.stamps, yaw_of(data.odom.rotations)
    t_tr, xy = data.prism_stamps, data.prism_positions[:, :2]
    est = timesync.estimate_offset(t_vo, yaw_vo, t_tr, xy, search=search, prism_in_base=data.base_T_prism[:3, 3])
    out: Dict[str, object] = {"timesync": est}
    try:
        out["timesync_baseline"] = timesync.cross_correlation_offset(t_vo, yaw_vo, t_tr, xy, search=search,
                                                                     track_heading="smoothed")
    except timesync.TimeSyncError as e:
        out["timesync_baseline"] = {"not_available": str(e)}
    if plot_dir:
        from ..evaluation import plot_coherence

        os.makedirs(plot_dir, exist_ok=True)
        base = out["timesync_baseline"]
        out["plot"] = plot_coherence(os.path.join(plot_dir, "timesync.png"), est,
                                     baseline=base if isinstance(base, timesync.OffsetEstimate) else None)
    return out
