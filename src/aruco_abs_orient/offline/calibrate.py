"""The camera's calibration from a recording: its marker observations and the solve (``calibrate``'s library).

In: a recording (a bag, split bags, or a VideoRecording), read without ROS (``bagio``): odometry, lever arms and
prism in a first pass, then the images streamed one by one, each searched whole for the map's markers
(``tracking.MarkerTracker`` without a prediction, so the nominal calibration cannot bias what is found). Out:
the observations (:func:`collect_observations`: time, id, camera-frame bearing, σ, image row), whether the map
fits them (:func:`map_check`) and the :class:`~aruco_abs_orient.calibration.Calibration` of
:func:`calibrate_bag`: the observations, the odometry and the prism track moved onto the camera clock (prism
stamp + ``time_offset``) through :func:`aruco_abs_orient.calibration.calibrate`. Errors: BagError (an unusable
recording), CalibrationError (the recording does not determine it: why).

Units: seconds, metres, radians.
"""

from __future__ import annotations

import math
from typing import List, Optional

import numpy as np

from ..calibration import Calibration, CalibrationError, CalibrationParams, Recording, Unknowns, calibrate
from ..calibration.bias import marker_cell_widths
from ..camera import SINGLE_CENTRE, DualFisheye
from ..detection import DetectionError, DetectorParams, MarkerDetector, decode_jpeg
from ..errors import AbsOrientError
from ..mapcheck import UNDETERMINED, MapCheckParams, MapVerdict, Sightings, check_map
from ..markers import MarkerMap
from ..pipeline import row_fraction
from ..tracking import MarkerTracker
from .bagio import BagData, BagTopics, bag_name, iter_images, read_bag_data

__all__ = ["CalibrateResult", "collect_observations", "map_check", "calibrate_bag"]


class CalibrateResult:
    """Observations of a bag as arrays (see :func:`collect_observations`)."""

    def __init__(self, data: BagData, times, ids, bearings, sigmas, frames: int, skipped: dict, rows=None,
                 corners=None, cell_px=None, pixel_pitch: float = float("nan")):
        self.data = data
        self.times = np.asarray(times, dtype=float).reshape(-1)          # s, camera clock
        self.ids = np.asarray(ids, dtype=int).reshape(-1)
        self.bearings = np.asarray(bearings, dtype=float).reshape(-1, 3)  # unit, camera frame
        self.sigmas = np.asarray(sigmas, dtype=float).reshape(-1)        # rad
        # image row of each, v/H − ½ (pipeline.row_fraction): the rolling shutter's time within the frame
        self.rows = np.zeros(len(self.times)) if rows is None else np.asarray(rows, dtype=float).reshape(-1)
        # corner bearings (N, 4, 3) of each, ArUco order (None: not kept)
        self.corners = None if corners is None else np.asarray(corners, dtype=float).reshape(-1, 4, 3)
        # width of each one's cells in the image along the azimuth and the elevation (px; None: not known) and the
        # image's pitch (rad/px)
        self.cell_px = None if cell_px is None else np.asarray(cell_px, dtype=float).reshape(-1, 2)
        self.pixel_pitch = float(pixel_pitch)
        self.frames = frames                                              # images searched
        self.skipped = skipped


def collect_observations(bag: str, marker_map: Optional[MarkerMap], topics: Optional[BagTopics] = None,
                         progress: bool = True, detector_params: Optional[DetectorParams] = None,
                         data: Optional[BagData] = None, every: int = 1,
                         label: str = "calibrate: detect", dictionary: str = "DICT_4X4_50") -> CalibrateResult:
    """Every marker observation of ``bag`` (with its corners): whole-frame detection of the map's markers in every
    ``every``-th image (30 fps frames a few cm apart add little but detection time), or of every marker of
    ``dictionary`` when ``marker_map`` is None (a map made from the recording); ``label`` names the progress bar
    (the command that runs it)."""
    if every < 1:
        raise CalibrationError(f"every: expected an integer ≥ 1, got {every}")
    topics = topics or BagTopics()
    data = data or read_bag_data(bag, topics)
    if marker_map is None:
        detector = MarkerDetector(dictionary, detector_params)
        find = detector.detect
    else:
        tracker = MarkerTracker(marker_map, detector_params)
        detector = tracker.detector

        def find(grey):
            return tracker.process(grey, None).observations
    cells_across = detector.backend.bits
    pitch = float("nan")
    times: List[float] = []
    ids: List[int] = []
    bearings: List[np.ndarray] = []
    sigmas: List[float] = []
    rows: List[float] = []
    corners: List[np.ndarray] = []
    cells: List[float] = []
    skipped: dict = {}
    frames = 0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=data.image_count, unit="frame", desc=label, dynamic_ncols=True)
    images = iter_images(bag, topics)
    try:
        for k, (stamp, payload) in _until_broken(images, skipped):
            if bar is not None:
                bar.update(1)
            if k % every:
                continue
            frames += 1
            try:
                if payload is None or not math.isfinite(stamp):
                    raise DetectionError("undecodable image message")
                grey = decode_jpeg(payload) if isinstance(payload, bytes) else payload
                found = find(grey)
                row = row_fraction(np.array([o.centre for o in found]).reshape(-1, 3), grey.shape[0])
                pitch = 2.0 * math.pi / grey.shape[1]
            except DetectionError as e:
                key = f"bad image: {str(e).split(':')[0]}"
                skipped[key] = skipped.get(key, 0) + 1
                continue
            for o, f in zip(found, row):
                times.append(stamp)
                ids.append(o.id)
                bearings.append(o.centre)
                sigmas.append(o.sigma)
                rows.append(float(f))
                corners.append(o.corners)
            if found:
                cells.extend(marker_cell_widths(np.array([o.centre for o in found]),
                                                np.array([o.corners for o in found]), cells_across) / pitch)
    finally:
        if bar is not None:
            bar.close()
    return CalibrateResult(data, times, ids, bearings, sigmas, frames, skipped, rows, np.array(corners), cells, pitch)


def _until_broken(images, skipped: dict):
    """``enumerate(images)`` up to a recording broken half-way (a video that cannot be decoded to its end):
    the frames before are kept, the reason is counted in ``skipped``."""
    k = 0
    while True:
        try:
            item = next(images)
        except StopIteration:
            return
        except AbsOrientError as e:  # the bag or video reader's own errors
            skipped[f"reading stopped: {e}"] = 1
            return
        yield k, item
        k += 1


def map_check(obs: CalibrateResult, marker_map: MarkerMap, time_offset: float,
              params: Optional[MapCheckParams] = None) -> MapVerdict:
    """Whether ``marker_map`` fits the observations (:func:`aruco_abs_orient.mapcheck.check_map` with ``params``)
    with the bag's own lever arms, the prism track on its clock (observations at camera time − ``time_offset``)."""
    d = obs.data
    if len(d.prism_stamps) < 2 or not len(obs.times):
        return MapVerdict(UNDETERMINED, "the marker map is not checked: no prism track or no marker seen", {})
    T, valid = d.odom.transforms_at(obs.times)
    rows = Sightings(obs.times[valid] - time_offset, obs.ids[valid], obs.bearings[valid], T[valid][:, :3, :3])
    return check_map(rows, (d.prism_stamps, d.prism_positions), {m.id: m.position for m in marker_map},
                     d.base_T_camera, d.base_T_prism[:3, 3], params, origin=marker_map.origin)


def calibrate_bag(bag: str, marker_map: MarkerMap, time_offset: float = 0.0, topics: Optional[BagTopics] = None,
                  progress: bool = True, unknowns: Optional[Unknowns] = None,
                  params: Optional[CalibrationParams] = None,
                  observations: Optional[CalibrateResult] = None, lenses: DualFisheye = SINGLE_CENTRE,
                  readout: float = 0.0) -> Calibration:
    """Calibrate the camera of ``bag`` against ``marker_map``.

    ``time_offset`` (s): camera stamps = total-station time + ``time_offset`` (``timesync``'s sign);
    ``unknowns`` (:class:`~aruco_abs_orient.calibration.Unknowns`, default the boresight only): with
    ``time_offset`` it is refined (the result's ``time_offset_delta`` is added to it); ``lever_arm`` the
    camera's origin; ``readout`` the camera's rolling-shutter readout time (the images' stamps are their
    middle rows' capture times; row v of H is captured at stamp + (v/H − ½)·readout).
    ``observations``: a :func:`collect_observations` result to reuse (detection is the slow part).
    ``lenses``: the camera's two lenses as known (``camera.DualFisheye``): fixed, or the start of their estimate.
    ``readout`` (s): the camera's rolling-shutter readout as known: fixed, or the start of its estimate.
    Raises BagError (unusable bag) or CalibrationError (the recording cannot determine it: why).
    """
    obs = observations or collect_observations(bag, marker_map, topics, progress)
    d = obs.data
    if len(d.prism_stamps) < 2:
        raise CalibrationError(f"{bag_name(bag)}: no prism track: the calibration needs the total station's "
                               "prism positions")
    rec = Recording(obs.times, obs.ids, obs.bearings, obs.sigmas, d.odom, d.prism_stamps + time_offset,
                    d.prism_positions, marker_map, d.base_T_camera, d.base_T_prism, obs.rows, lenses,
                    obs.cell_px, obs.pixel_pitch)
    cal = calibrate(rec, unknowns, params, readout=readout)
    for k, v in obs.skipped.items():
        cal.skipped[k] = cal.skipped.get(k, 0) + v
    return cal
