"""Offline processing of a recorded bag: images → markers → absolute yaw → map→odom → files.

Reads the bag twice with rosbags (no ROS master): a first pass for tf, tf_static and the prism,
then the images streamed through a bounded queue by a reader thread whose JPEGs two decoder
threads decode (the decoders release the GIL, so decoding and detection use both cores), while
memory stays flat with the length of the recording. With ``tracking.decode_rows`` only the rows the
tracker's plan after the last image says the next ones read are decoded (:mod:`..detection.jpegrows`;
a frame a search then needs whole is decoded whole by the tracker: the same observations).

Outputs in ``out_dir`` (each written atomically: complete or absent):
- ``trajectory.tum``: base_link in map, one line per image with a pose, stamps in total-station time,
  positions in full coordinates (the marker map's ``origin`` added back);
- ``trajectory.csv`` (``full_coordinates``): t, E, N, H, roll, pitch, heading (degrees), for a surveyor;
- ``observations.csv``: one row per marker observation;
- ``heading_sigma.csv``: ``time, heading_deg, sigma_deg`` of each pose: the filter's heading of base_link and
  its own 1-σ (what the report's heading-error plot draws as the filter's band);
- ``summary.json``: counts, rates, settings, what was skipped and why, the start of the recording, which north
  the headings are referred to (``north``: the map's grid north; with its ``grid`` and ``origin`` the meridian
  convergence, ``meridian_convergence_deg``, that turns them to true north), the self-checks
  (:mod:`aruco_abs_orient.selfcheck`; their findings are warnings too), ``decoding`` (how the images were
  decoded: the share of their rows, the frames decoded in part, those a search then decoded whole, and why whole
  frames when the row decoder is off or missing) and the map check (:mod:`aruco_abs_orient.mapcheck`: does the
  marker map fit the recording?).

A marker map that does not fit the recording (another site's, rotated, shifted, scaled, a wrong origin) gets
no trajectory: ``trajectory.tum`` is not written (an older one in ``out_dir`` is removed) unless
``RunSetup.force``; the summary's ``map_check`` says why.
"""

from __future__ import annotations

import csv
import json
import math
import os
import queue
import shlex
import tempfile
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from typing import Dict, List, NamedTuple, Optional

import numpy as np

from ..detection import DetectionError, decode_jpeg
from ..detection.jpegrows import decode_jpeg_rows, row_decoder
from ..mapcheck import DOES_NOT_FIT, UNDETERMINED, MapCheckParams, MapVerdict, SightingSample, check_map
from ..markers import MarkerMap
from ..north import NorthReference
from ..params import Tunables, parse_params
from ..pipeline import AbsOrientPipeline, FrameResult
from ..selfcheck import ModelContext, RunContext, check_run, observation_columns
from ..transforms import yaw_of
from ..tum import RESULT_FILE_MODE, Trajectory, atomic_write_text, write_tum
from .bagio import (
    BagData,
    BagReadError,
    Bags,
    BagTopics,
    bag_paths,
    bags_for_shell,
    iter_images,
    open_reader,
    read_bag_data,
    salvage_bag,
)
from .commandlines import calibrate_command

__all__ = ["ProcessResult", "RunSetup", "process_bag", "OBSERVATION_COLUMNS"]

PRISM_LOOKAHEAD = 2.0  # s of prism samples ahead of the image handed to the pipeline (interpolation)

OBSERVATION_COLUMNS = [
    "time", "id", "method", "azimuth_deg", "elevation_deg", "pixel_u", "pixel_v", "angular_size_deg",
    "bearing_sigma_deg", "range_m", "yaw_deg", "yaw_sigma_deg", "residual_deg", "accepted", "reason",
]


@dataclass
class ProcessResult:
    """What :func:`process_bag` produced (paths) and measured."""

    trajectory_path: str
    observations_path: str
    summary_path: str
    summary: Dict[str, object] = field(default_factory=dict)
    extra_paths: List[str] = field(default_factory=list)


def _deg(x: float) -> str:
    return "" if x is None or not math.isfinite(x) else f"{math.degrees(x):.5f}"


def _observation_rows(res: FrameResult) -> List[list]:
    rows = []
    for r in res.observations:
        o = r.observation
        rows.append([
            f"{res.stamp:.6f}", o.id, o.method, _deg(o.azimuth), _deg(o.elevation), f"{o.pixel[0]:.3f}",
            f"{o.pixel[1]:.3f}", _deg(o.angular_size), _deg(o.sigma),
            "" if not math.isfinite(r.range) else f"{r.range:.4f}", _deg(r.yaw), _deg(r.yaw_sigma),
            _deg(r.residual), int(r.accepted), r.reason,
        ])
    return rows


class _RowHint:
    """The rows the decoders decode of the k-th image (0: the first): what the tracker's plan after the last image
    processed (the ``index``-th) says the next ones read; None: the whole image."""

    def __init__(self):
        self._state: tuple = (-1, None)   # (index, RowPlan): replaced whole, read whole, by two threads

    def update(self, index: int, pipe: AbsOrientPipeline, height: int) -> None:
        self._state = (index, pipe.tracker.row_plan(height))

    def rows(self, k: int):
        index, plan = self._state
        return None if plan is None or k <= index else plan.rows(k - index - 1)


def _decoded(payload, reduce: int, hint: Optional[_RowHint] = None, k: int = 0):
    """A grey image (with ``hint``, only the rows it gives for the k-th image: a RowFrame), or the reason there is
    none (a string). The rows are asked when the decoding starts, from the freshest plan."""
    if payload is None:
        return "undecodable image message"
    if not isinstance(payload, bytes):
        return payload
    try:
        return decode_jpeg(payload, reduce=reduce) if hint is None else decode_jpeg_rows(payload, hint.rows(k))
    except DetectionError as e:
        return f"corrupt image: {e}"


def _row_hint(tunables: Tunables) -> tuple:
    """(the decoders' :class:`_RowHint`, or None for whole frames; how the frames are decoded, for the summary)."""
    if not tunables.tracking.decode_rows or int(tunables.pipeline.jpeg_reduce) != 1:
        return None, "whole frames (tracking.decode_rows is off, or pipeline.jpeg_reduce is not 1)"
    lib, why = row_decoder()
    if lib is None:
        return None, f"whole frames: {why}"
    return _RowHint(), "the rows tracking reads (jpegrows)"


def _reader(path: str, topics: BagTopics, reduce: int, out: queue.Queue, stop: threading.Event,
            decoders: ThreadPoolExecutor, hint: Optional[_RowHint]) -> None:
    """Producer thread: (stamp, future of a grey image or an error string) in bag order, then None. The JPEGs
    are decoded by ``decoders`` (libjpeg releases the GIL: on 2 cores the decoding of the next frames fills
    whatever the pipeline leaves, instead of one thread decoding while the other core waits), only the rows
    ``hint`` gives when there is one."""
    try:
        for k, (stamp, payload) in enumerate(iter_images(path, topics)):
            if stop.is_set():
                return
            out.put((stamp, decoders.submit(_decoded, payload, reduce, hint, k)))
    except Exception as e:  # a bag or video broken half-way: keep what was read, say why it stopped
        out.put((float("nan"), _done(f"reading stopped: {e}")))
    finally:
        out.put(None)


def _yield_to_pipeline() -> None:
    """A decoder thread's start: it runs at a lower priority (nice + 5) than the pipeline's thread, whose work
    is the run's critical path; the decoders fill what the pipeline leaves of the cores (4 frames ahead)."""
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + 5)
    except (AttributeError, OSError):  # not Linux: as before
        pass


def _done(value) -> Future:
    future: Future = Future()
    future.set_result(value)
    return future


def _selfcheck(checked, data: BagData, marker_map: MarkerMap, stamps, poses, summary, bag, pipe: AbsOrientPipeline,
               tunables: Tunables) -> Dict:
    """The run's self-checks (:func:`aruco_abs_orient.selfcheck.check_run`, with calibrate's model on the run's
    bearings and the mounting, lenses and offset the pipeline used) with the commands that fix what they find;
    each finding is also a warning of the summary."""
    obs = observation_columns(checked)
    bags, markers = bags_for_shell(bag), shlex.quote(marker_map.source)
    commands = {"timesync": f"aruco-abs-orient timesync {bags} --markers {markers}",
                "calibrate": calibrate_command(bag, marker_map.source, summary["time_offset_s"], data.image_rate)}
    yaws = yaw_of(np.array(poses).reshape(-1, 4, 4)[:, :3, :3]).tolist()
    offset = summary["time_offset_s"]
    odometry = Trajectory(data.odom.stamps - offset, data.odom.positions, data.odom.quats)   # the TS clock
    model = ModelContext(marker_map, odometry, pipe.base_T_camera, pipe.base_T_prism, pipe.lenses, pipe.readout,
                         tunables.calibration)
    result = check_run(obs, (data.prism_stamps, data.prism_positions), {m.id: m.position for m in marker_map},
                       (stamps, yaws), RunContext(summary["pipeline_stats"], summary["frames"], offset, commands,
                                                  pipe.base_T_prism[:3, 3], model), tunables.selfcheck)
    summary["warnings"] = list(summary["warnings"]) + [f["message"] for f in result["findings"]]
    return result


class RunSetup(NamedTuple):
    """How :func:`process_bag` runs, beside the tunables.

    ``time_offset`` (s): camera/VO stamps = total-station time + ``time_offset`` (the value the timesync tool
    estimates). ``topics``: the bag's topics and frames (None: :class:`.bagio.BagTopics`' defaults).
    ``calibration``: ``{"camera": base_T_camera, "prism": base_T_prism}`` (``calibration.load_calibration``)
    used instead of the bag's /tf_static lever arms, with its camera ``"lenses"`` and its rolling-shutter
    ``"readout"`` (s) when it has them. ``full_coordinates``: also write ``trajectory.csv``. ``progress``: show
    a progress bar. ``force``: write the trajectory even when the marker map does not fit the recording.
    """

    time_offset: float = 0.0
    topics: Optional[BagTopics] = None
    calibration: Optional[Dict] = None
    full_coordinates: bool = False
    progress: bool = True
    force: bool = False


def process_bag(bag: Bags, marker_map: MarkerMap, out_dir: str, setup: Optional[RunSetup] = None,
                tunables: Optional[Tunables] = None, data: Optional[BagData] = None) -> ProcessResult:
    """Process ``bag`` (one bag, or the files of one split recording, read as one in time order) into
    ``out_dir`` (created if needed), as :class:`RunSetup` says (None: its defaults), with ``tunables``
    (``params.load_params``; None: every default). ``bag`` may also be a :class:`.video.VideoRecording` (a
    video, its VO trajectory and prism log); ``data``: its :func:`.bagio.read_bag_data`, when already read.
    Raises BagError when the bag cannot be used at all.
    """
    setup = setup or RunSetup()
    topics = setup.topics or BagTopics()
    setup = setup._replace(topics=topics)
    tunables = tunables or parse_params({})
    north = NorthReference.make("grid", marker_map.grid, marker_map.origin, f"{marker_map.source}: ")
    t_start = (time.perf_counter(), time.process_time(), time.thread_time())  # wall, CPU, this thread's CPU
    os.makedirs(out_dir, exist_ok=True)
    readable, salvaged, notes = (bag if hasattr(bag, "iter_images") else bag_paths(bag)), [], []
    if data is None:
        try:
            data = read_bag_data(bag, topics)
        except BagReadError:  # a recording cut short (the last split of a crash): process its complete chunks
            readable, salvaged, notes = _salvage(bag_paths(bag), out_dir)
            data = read_bag_data(readable, topics)
            data.warnings.extend(notes)
    try:
        return _process(bag, readable, data, marker_map, out_dir, setup, tunables, t_start, north)
    finally:
        for path in salvaged:
            if os.path.exists(path):
                os.unlink(path)


def _salvage(paths: List[str], out_dir: str):
    """(readable paths, temporary files, warnings): each file rosbags cannot open is replaced by its complete
    chunks, re-indexed into a temporary bag in ``out_dir``."""
    readable, salvaged, notes = [], [], []
    for k, path in enumerate(paths):
        try:
            open_reader(path).close()
            readable.append(path)
            continue
        except BagReadError as e:
            fixed = os.path.join(out_dir, f".salvaged.{os.getpid()}.{k}.bag")
            salvaged.append(fixed)
            n, last = salvage_bag(path, fixed)
            readable.append(fixed)
            notes.append(f"{e}: processed the {n} messages of its complete chunks (up to t = {last:.3f} s)")
    return readable, salvaged, notes


def _make_pipeline(marker_map: MarkerMap, data: BagData, calibration: Optional[Dict],
                   tunables: Tunables) -> AbsOrientPipeline:
    """The pipeline with the bag's lever arms, or the calibration file's mounting, lenses and readout."""
    base_T_camera, base_T_prism = data.base_T_camera, data.base_T_prism
    readout = 0.0
    if calibration is not None:
        base_T_camera, base_T_prism = calibration["camera"], calibration["prism"]
        readout = float(calibration.get("readout", 0.0))
    return AbsOrientPipeline(marker_map, base_T_camera, base_T_prism, readout=readout,
                             calibrated=calibration is not None, **tunables.pipeline_kwargs(),
                             lenses=None if calibration is None else calibration.get("lenses"),
                             lens_yaw_sigma=None if calibration is None else calibration.get("lens_yaw_sigma"))


def _count(counter: Dict[str, int], key: str) -> None:
    counter[key] = counter.get(key, 0) + 1


@dataclass
class _Tally:
    """What the frames of a run add up to: the poses (stamps, map_T_base, the filter's yaw 1-σ in rad), the
    counters, the marker yaws for the self-checks (selfcheck.YawObservation's) and the sightings for the map
    check ((t, id, bearing, odom rotation), evenly thinned), and how far the prism and IMU samples were fed."""

    sighted: SightingSample
    stamps: List[float] = field(default_factory=list)
    poses: List[np.ndarray] = field(default_factory=list)
    sigmas: List[float] = field(default_factory=list)
    errors: Dict[str, int] = field(default_factory=dict)
    frames: int = 0
    with_pose: int = 0
    first_pose: Optional[float] = None
    odom_missing: int = 0
    timing_sum: Dict[str, float] = field(default_factory=dict)
    checked: List[tuple] = field(default_factory=list)
    modes: Dict[str, int] = field(default_factory=dict)
    tilt_sources: Dict[str, int] = field(default_factory=dict)
    next_prism: int = 0
    next_imu: int = 0
    rows: Dict[str, object] = field(default_factory=lambda: {"frames": 0, "in_part": 0, "completed": 0, "share": 0.0})

    def decoded(self, image: np.ndarray) -> None:
        """An image processed: the share of its rows decoded, whether it was decoded in part, and whole later."""
        span = getattr(image, "rows", None) or (0, image.shape[0])
        self.rows["frames"] += 1
        self.rows["in_part"] += span != (0, image.shape[0])
        self.rows["completed"] += bool(getattr(image, "completed", False))
        self.rows["share"] += (span[1] - span[0]) / image.shape[0]

    def add(self, res: FrameResult, T_odom: np.ndarray) -> None:
        """One processed frame's timings, counters, marker yaws, sightings and pose."""
        for k, v in res.timings.items():
            self.timing_sum[k] = self.timing_sum.get(k, 0.0) + v
        if res.tilt_source:
            _count(self.tilt_sources, res.tilt_source)
        if res.tracking is not None:
            _count(self.modes, res.tracking.mode)
        if res.error:
            _count(self.errors, res.error.split(":")[0])
        odom_yaw = float(yaw_of(T_odom[:3, :3]))
        self.checked += [(res.stamp, r.observation.id, r.observation.azimuth, r.observation.elevation, r.yaw_sigma,
                          r.residual, r.accepted, r.yaw, odom_yaw, r.observation.sigma)
                         for r in res.observations if math.isfinite(r.yaw)]
        for r in res.observations:
            self.sighted.add(res.stamp, r.id, r.observation.centre, T_odom[:3, :3])
        if res.map_T_base is not None:
            if not self.with_pose:
                self.first_pose = res.stamp
            self.with_pose += 1
            self.stamps.append(res.stamp)
            self.poses.append(res.map_T_base)
            self.sigmas.append(math.nan if res.yaw_sigma is None else res.yaw_sigma)


def _feed(pipe: AbsOrientPipeline, data: BagData, tally: _Tally, stamp: float, time_offset: float) -> None:
    """The prism samples up to PRISM_LOOKAHEAD s after the image at ``stamp`` (camera clock), the IMU's up to
    it, to the pipeline (it keeps a bounded window)."""
    t = stamp - time_offset
    while tally.next_prism < len(data.prism_stamps) and data.prism_stamps[tally.next_prism] <= t + PRISM_LOOKAHEAD:
        pipe.add_prism(float(data.prism_stamps[tally.next_prism]), data.prism_positions[tally.next_prism])
        tally.next_prism += 1
    while tally.next_imu < len(data.imu_stamps) and data.imu_stamps[tally.next_imu] <= stamp:
        pipe.add_imu(float(data.imu_stamps[tally.next_imu]) - time_offset, *data.imu_tilts[tally.next_imu])
        tally.next_imu += 1


def _frames(items: queue.Queue, writer, pipe: AbsOrientPipeline, data: BagData, tally: _Tally,
            time_offset: float, bar, hint: Optional[_RowHint]) -> None:
    """The frame loop: each decoded image (or why there is none) from the reader through the pipeline, its
    observations to ``writer`` (observations.csv), the rest into ``tally``; until the reader's None. After each
    image the tracker's plan of the rows it reads next goes to ``hint`` (when the decoders decode rows)."""
    writer.writerow(OBSERVATION_COLUMNS)
    while True:
        item = items.get()
        if item is None:
            break
        stamp, image = item[0], item[1].result()
        tally.frames += 1
        if bar is not None:
            bar.update(1)
        if isinstance(image, str):
            if image.startswith("reading stopped"):
                data.warnings.append(image)
            _count(tally.errors, image.split(":")[0])
            continue
        T_odom, valid = data.odom.transforms_at(stamp)
        if not bool(valid):
            tally.odom_missing += 1
            continue
        _feed(pipe, data, tally, stamp, time_offset)
        res = pipe.process_image(stamp - time_offset, image, T_odom)
        if hint is not None:
            hint.update(tally.frames - 1, pipe, image.shape[0])
        tally.decoded(image)
        tally.add(res, T_odom)
        writer.writerows(_observation_rows(res))


def _write_trajectory(out_dir: str, tally: _Tally, marker_map: MarkerMap, north: NorthReference, refused: bool,
                      full_coordinates: bool):
    """(trajectory.tum's path, the extra files): the trajectory in full coordinates, trajectory.csv when asked,
    heading_sigma.csv; ``refused`` (the map does not fit): none, and an older run's trajectory removed ('')."""
    traj_path = os.path.join(out_dir, "trajectory.tum")
    if refused:
        for stale in (traj_path, os.path.join(out_dir, "trajectory.csv")):  # an older run's: not this map's
            if os.path.exists(stale):
                os.unlink(stale)
        return "", []
    stamps, poses, sigmas = tally.stamps, tally.poses, tally.sigmas
    traj = Trajectory.from_transforms(stamps, np.array(poses).reshape(-1, 4, 4))
    traj = traj._replace(positions=marker_map.to_full(traj.positions))
    origin = "" if marker_map.origin is None else (" in full coordinates (map origin "
                                                   f"{', '.join(f'{x:.3f}' for x in marker_map.origin)} added)")
    write_tum(traj_path, traj,
              header=f"base_link in map{origin} (aruco_abs_orient process); t in total-station time; "
                     f"headings referred to {north.describe()}")
    extra = [write_full_csv(os.path.join(out_dir, "trajectory.csv"), traj)] if full_coordinates else []
    atomic_write_text(os.path.join(out_dir, "heading_sigma.csv"), "time,heading_deg,sigma_deg\n" + "".join(
        f"{t:.6f},{_deg(float(yaw_of(T[:3, :3])))},{_deg(s)}\n" for t, T, s in zip(stamps, poses, sigmas)))
    return traj_path, extra


def _timings(t_start: tuple, duration: float) -> Dict[str, object]:
    """summary.json's timings since ``t_start`` (wall, CPU, this thread's CPU) of a recording ``duration`` s long:
    the whole run, its checks included."""
    wall, cpu, pipeline_cpu = (now - then for now, then in zip(
        (time.perf_counter(), time.process_time(), time.thread_time()), t_start))
    return {"wall_time_s": wall, "real_time_factor": duration / wall if wall > 0 else None,
            # CPU seconds of all threads, and of the one running the pipeline (the others read and decode): on N
            # free cores the wall time would be about max(pipeline, all / N)
            "cpu_time_s": {"all_threads": cpu, "pipeline_thread": pipeline_cpu}}


def _summary(bag, marker_map: MarkerMap, setup: RunSetup, pipe: AbsOrientPipeline, data: BagData, tally: _Tally,
             params, north: NorthReference) -> Dict[str, object]:
    """summary.json's content but for the map check, the self-checks and the timings (:func:`_timings`): counts,
    rates, settings, what was skipped and why, the pipeline's ``params``; a run without a pose says why in its
    warnings."""
    frames = tally.frames
    duration = max(data.end - data.start, 0.0)
    reason = pipe.waiting_reason if tally.with_pose == 0 else ""
    if reason:
        data.warnings.append(f"no pose in {frames} frame(s): the map→odom filter never started: {reason}")
    return {
        "bag": (os.path.abspath(bag) if isinstance(bag, str) else os.path.abspath(bag.video) if hasattr(bag, "video")
                else [os.path.abspath(b) for b in bag_paths(bag)]),
        "markers": marker_map.source,
        "time_offset_s": setup.time_offset,
        "lever_arms": "calibration file" if setup.calibration is not None else "bag /tf_static",
        "readout_ms": 1e3 * pipe.readout,   # the rolling shutter's, from the calibration file (0: global shutter)
        "frames": frames,
        "frames_with_pose": tally.with_pose,
        "no_pose_reason": reason,
        "filter": {"initialised_at": tally.first_pose, "lockout_recoveries": pipe.filter.stats.lockout_recoveries,
                   "reinitialisations": pipe.filter.stats.reinitialisations,
                   "yaw_noise_scale": pipe.filter.stats.noise_scale},
        "frames_without_odometry": tally.odom_missing,
        "mode": "markers only (no prism)" if params.markers_only else "prism and markers",
        "imu_samples": int(len(data.imu_stamps)),
        "tilt_sources": tally.tilt_sources,
        "prism_samples": int(len(data.prism_stamps)),
        "skipped": {**data.skipped, **tally.errors},
        "warnings": data.warnings,
        "pipeline_stats": dict(pipe.stats),
        "search_modes": tally.modes,
        "decoding": {**tally.rows, "share": tally.rows["share"] / max(tally.rows["frames"], 1)},
        "mean_ms_per_frame": {k: v / max(frames, 1) for k, v in tally.timing_sum.items()},
        "params": asdict(params),
        "bag_duration_s": duration,
        "recording_start_s": float(data.start),
        "north": north.describe(),
        "meridian_convergence_deg": math.degrees(north.gamma),
    }


def _process(bag, readable, data: BagData, marker_map, out_dir, setup: RunSetup, tunables: Tunables,
             t_start: tuple, north: NorthReference) -> ProcessResult:
    """process_bag's work on ``readable`` (the bag(s), or what was salvaged of them); ``bag`` is the user's;
    ``north`` what the headings are referred to (the map's grid north)."""
    time_offset, topics, calibration, full_coordinates, progress, force = setup
    params = tunables.pipeline
    pipe = _make_pipeline(marker_map, data, calibration, tunables)
    fd, obs_tmp = tempfile.mkstemp(prefix=".observations.csv.", suffix=".tmp", dir=out_dir)
    os.fchmod(fd, RESULT_FILE_MODE)
    tally = _Tally(SightingSample(tunables.mapcheck.max_sightings))
    items: queue.Queue = queue.Queue(maxsize=4)  # with the frames being decoded: ≤ 4 + 2 frames in memory
    stop = threading.Event()
    decoders = ThreadPoolExecutor(max_workers=min(2, os.cpu_count() or 1), thread_name_prefix="jpeg",
                                  initializer=_yield_to_pipeline)
    hint, tally.rows["decoder"] = _row_hint(tunables)
    # reduced decoding is done by the reader: the pipeline then receives grey arrays
    reader = threading.Thread(target=_reader, args=(readable, topics, int(params.jpeg_reduce), items, stop,
                                                    decoders, hint), daemon=True)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=data.image_count, unit="frame", desc="process", dynamic_ncols=True)
    reader.start()
    try:
        with os.fdopen(fd, "w", newline="") as f:
            _frames(items, csv.writer(f), pipe, data, tally, time_offset, bar, hint)
        stop.set()
        map_check = _map_check(tally.sighted, data, marker_map, pipe, params.markers_only, tunables.mapcheck)
        traj_path, extra = _write_trajectory(out_dir, tally, marker_map, north,
                                             map_check.status == DOES_NOT_FIT and not force, full_coordinates)
        obs_path = os.path.join(out_dir, "observations.csv")
        os.replace(obs_tmp, obs_path)
    except BaseException:
        stop.set()
        if os.path.exists(obs_tmp):
            os.unlink(obs_tmp)
        raise
    finally:
        decoders.shutdown(wait=False)
        if bar is not None:
            bar.close()
    summary = _summary(bag, marker_map, setup, pipe, data, tally, params, north)
    summary["map_check"] = map_check.as_dict()
    summary["selfcheck"] = _selfcheck(tally.checked, data, marker_map, tally.stamps, tally.poses, summary, bag, pipe,
                                      tunables)
    if map_check.status == DOES_NOT_FIT:  # first: the self-checks' findings follow from it
        found = {f["message"] for f in summary["selfcheck"]["findings"]}
        summary["warnings"] = [map_check.message] + [w for w in summary["warnings"] if w not in found]
    summary.update(_timings(t_start, summary["bag_duration_s"]))
    summary_path = os.path.join(out_dir, "summary.json")
    atomic_write_text(summary_path, json.dumps(summary, indent=2, default=float) + "\n")
    return ProcessResult(traj_path, obs_path, summary_path, summary, extra)


def _map_check(sighted: SightingSample, data: BagData, marker_map: MarkerMap, pipe: AbsOrientPipeline,
               markers_only: bool, params: MapCheckParams) -> MapVerdict:
    """Whether the marker map fits what the run saw (:func:`aruco_abs_orient.mapcheck.check_map`): the
    sightings along the prism track, with the lever arms the pipeline used (markers only: not checked here)."""
    if markers_only or len(data.prism_stamps) < 2:
        return MapVerdict(UNDETERMINED, "the marker map is not checked without a prism track", {})
    return check_map(sighted.sightings(), (data.prism_stamps, data.prism_positions),
                     {m.id: m.position for m in marker_map}, pipe.base_T_camera, pipe.base_T_prism[:3, 3],
                     params, origin=marker_map.origin)


def write_full_csv(path: str, traj: Trajectory) -> str:
    """``t, E, N, H, roll_deg, pitch_deg, heading_deg`` of a trajectory in full coordinates (heading: yaw,
    counter-clockwise from E as in the map frame), mm and mdeg resolution; returns ``path``."""
    from ..transforms import matrix_to_rpy

    lines = ["t,E,N,H,roll_deg,pitch_deg,heading_deg"]
    for t, p, R in zip(traj.stamps, traj.positions, traj.rotations):
        r, pi, y = (math.degrees(float(a)) for a in matrix_to_rpy(R))
        lines.append(f"{t:.6f},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f},{r:.4f},{pi:.4f},{y:.4f}")
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path
