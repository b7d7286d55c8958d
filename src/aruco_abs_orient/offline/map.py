"""The marker map from a recording (the library part of ``aruco-abs-orient map``).

In: a recording (a bag, split bags, or a video with its VO trajectory and prism log) with its topics, the time
offset, the markers' size and dictionary, the control markers (a map, possibly empty), the camera's calibration
(the ``calibrate`` file's contents, or empty: the bag's /tf_static and the params' lenses), what to estimate
besides the markers (:class:`~aruco_abs_orient.mapping.MapUnknowns`) and the params. Every ``every``-th image
is searched whole for every marker of the dictionary (``collect_observations`` without a map: centres and
corners), and the network (:func:`aruco_abs_orient.mapping.map_markers`) places each marker in the total
station's frame with its covariance.
Out: :class:`MapRun` (the network's result, the marker map it makes, the comparison with an older map, the
CPU time) and :func:`write_map`: the markers YAML, ``<out>_report.md`` and ``<out>_plan.png``.
Errors: MappingError (nothing can be placed, no prism track: a :class:`~aruco_abs_orient.errors.NoResultError`
status), the reader's errors for bad input.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from typing import NamedTuple, Optional

from ..calibration import Recording
from ..errors import NoResultError
from ..mapping import MappingError, MapUnknowns, map_markers
from ..mapping.compare import compare_maps
from ..mapping.output import mapped_map, mapped_yaml, plot_plan, report_markdown
from ..markers import MarkerMap
from ..params import Tunables
from ..tum import atomic_write_text
from .bagio import BagTopics, bag_name, read_bag_data
from .calibrate import collect_observations

__all__ = ["MapRun", "NothingMappedError", "load_control", "map_recording", "report_paths", "write_map"]


class NothingMappedError(NoResultError):
    """The recording places no marker (or has no prism track): the message says why and what to drive."""


class MapRun(NamedTuple):
    """What :func:`map_recording` found."""

    name: str                       # the recording's name, for messages and the report
    result: object                  # mapping.MapResult
    markers: MarkerMap              # the mapped markers (those placed)
    comparison: Optional[object]    # mapping.compare's comparison with the older map, if one was given
    elapsed: float                  # s, the network's time


def load_control(path: str, dictionary: str, size: float, sigma: float) -> MarkerMap:
    """The control markers of ``path``: a markers YAML (.yaml, .yml) or a survey file (``survey.read_points``)."""
    if path.lower().endswith((".yaml", ".yml")):
        control = MarkerMap.load(path)
        if control.dictionary != dictionary:
            raise MappingError(f"{path}: dictionary {control.dictionary}, but --dictionary {dictionary}: expected the "
                               "same markers")
        return control
    from ..survey import marker_map_from_points, read_points

    return marker_map_from_points(read_points(path), dictionary, size, sigma=sigma, source=path)


def report_paths(out: str):
    """The report and plan written beside the markers YAML ``out``: ``site/markers.yaml`` →
    ``site/markers_report.md``, ``site/markers_plan.png``."""
    root, ext = os.path.splitext(out)
    root = root if ext in (".yaml", ".yml") else out
    return root + "_report.md", root + "_plan.png"


def map_recording(recording, topics: BagTopics, time_offset: float, size: float, dictionary: str,
                  control: MarkerMap, calibration: dict, unknowns: MapUnknowns, tunables: Tunables,
                  readout: Optional[float] = None, heading_model: Optional[str] = None, every: int = 1,
                  old: Optional[MarkerMap] = None, progress: bool = True) -> MapRun:
    """The markers of ``recording`` placed by the network (see the module's docstring); ``readout`` (s) None: the
    calibration's, else 0."""
    data = read_bag_data(recording, topics)
    detection = dataclasses.replace(tunables.detection, pattern_fit=tunables.mapping.pattern_fit)
    obs = collect_observations(recording, None, topics, progress=progress, detector_params=detection,
                               data=data, every=every, label="map: detect", dictionary=dictionary)
    name = bag_name(recording)
    if len(data.prism_stamps) < 2:
        raise NothingMappedError(f"{name}: no prism track: the map needs the total station's prism positions")
    readout = float(calibration.get("readout", 0.0)) if readout is None else readout
    rec = Recording(obs.times, obs.ids, obs.bearings, obs.sigmas, data.odom, data.prism_stamps + time_offset,
                    data.prism_positions, control, calibration.get("camera", data.base_T_camera),
                    calibration.get("prism", data.base_T_prism), obs.rows,
                    calibration.get("lenses", tunables.pipeline.lenses()))
    params = tunables.calibration
    if heading_model is not None:
        params = dataclasses.replace(params, heading_model=heading_model)
    t0 = time.perf_counter()
    try:
        result = map_markers(rec, obs.corners, size, unknowns, params, tunables.mapping, readout)
    except MappingError as e:
        raise NothingMappedError(f"{name}: cannot map the markers: {e}") from None
    elapsed = time.perf_counter() - t0
    if "camera" not in calibration and not unknowns.boresight and math.isfinite(result.yaw_walk):
        result.warnings.append(
            "the camera's mounting is the recording's nominal one (no --calibration, no --boresight): its error "
            "turns map→odom's yaw as the platform turns, so the walk and drift the report gives are not the "
            "odometry's alone; do not set the filter's yaw_random_walk from them (calibrate the camera first, or "
            "add --boresight)")
    mm = mapped_map(result, size, dictionary, origin=control.origin, sizes={m.id: m.size for m in control})
    for k, v in obs.skipped.items():
        result.skipped[k] = result.skipped.get(k, 0) + v
    if not len(mm):
        raise NothingMappedError(f"{name}: no marker could be placed: " + "; ".join(
            f"{m.id}: {m.reason}" for _, m in sorted(result.markers.items())))
    comparison = compare_maps(mm, old, tunables.mapping.compare_alpha) if old is not None else None
    return MapRun(name, result, mm, comparison, elapsed)


def write_map(run: MapRun, out: str) -> tuple:
    """The markers YAML ``out`` and its report and plan beside it (:func:`report_paths`, returned)."""
    report, plan = report_paths(out)
    atomic_write_text(out, mapped_yaml(run.result, run.markers, run.name))
    plot_plan(run.result, plan, os.path.basename(out))
    atomic_write_text(report, report_markdown(run.result, run.name, os.path.basename(plan), run.comparison,
                                              run.elapsed))
    return report, plan
