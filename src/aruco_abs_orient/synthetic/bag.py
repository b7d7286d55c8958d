"""Write a synthetic scenario as a ROS 1 bag (rosbags, no ROS needed) plus its truth files.

``generate(config, out_dir)`` writes into ``out_dir``:

- ``scenario.bag``: ``/camera/image/compressed`` (sensor_msgs/CompressedImage, jpeg, frame
  ``camera``), ``/tf`` (tf2_msgs/TFMessage, ``odom → base_link`` at each image), both stamped on
  the camera clock (true time + ``camera_time_offset``); ``/tf_static`` (latched: ``base_link →
  camera`` with the NOMINAL rotation, ``base_link → prism``); ``/ms60/prism``
  (geometry_msgs/PointStamped, frame ``map``, stamped with true time); with ``imu_rate`` > 0 also
  ``/imu/data`` (sensor_msgs/Imu, frame ``base_link``, camera clock: roll/pitch with noise, the true yaw,
  gravity as the acceleration). Each message is recorded at its header stamp.
- ``truth.tum``: base_link in map at each image's TRUE capture time (one line per image).
- ``markers.yaml``: the surveyed marker map; ``hidden.yaml``: the scenario's parameters and
  hidden truth (seed, time offset, boresight error, drift), enough for ``Scenario.from_hidden``.

Every file is written under a temporary name and renamed when complete. Frames are rendered on
``workers`` processes (ordered), with a tqdm progress bar on stderr.
"""

from __future__ import annotations

import heapq
import math
import multiprocessing
import os
import sys
import tempfile
import time
from typing import Iterator, List, NamedTuple, Optional, Tuple

import numpy as np

from ..errors import InputFileError
from ..transforms import matrix_to_quat, matrix_to_rpy, rpy_to_matrix
from ..tum import Trajectory, write_tum
from .render import PROFILES, encode_jpeg
from .scenario import Scenario, ScenarioConfig
from .world import render_frame

__all__ = ["GenerateError", "GeneratedScenario", "generate", "describe", "OUTPUT_FILES", "TOPICS", "make_typestore",
           "Messages"]

OUTPUT_FILES = ("scenario.bag", "truth.tum", "markers.yaml", "hidden.yaml")
TOPICS = {
    "/camera/image/compressed": "sensor_msgs/msg/CompressedImage",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/ms60/prism": "geometry_msgs/msg/PointStamped",
}
IMU_TOPIC = "/imu/data"


class GenerateError(InputFileError):
    """The scenario could not be written (output directory, existing files)."""


class GeneratedScenario(NamedTuple):
    """Paths of the outputs and what was made: ``frames`` images in ``seconds`` of wall time."""

    out_dir: str
    bag: str
    truth: str
    markers: str
    hidden: str
    frames: int
    prism_samples: int
    seconds: float


def make_typestore():
    """rosbags' ROS1 Noetic typestore plus tf2_msgs/TFMessage (md5 94810edda583a504dfda3829e70d7eec)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    if "tf2_msgs/msg/TFMessage" not in store.types:
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\n", "tf2_msgs/msg/TFMessage"))
    return store


# ---- rendering (worker processes) -------------------------------------------------------------

_WORKER: dict = {}


def _init_worker(config: ScenarioConfig) -> None:
    import cv2

    cv2.setNumThreads(1)  # one process per core
    _WORKER["scenario"] = Scenario(config)


def _render_frame(index: int) -> bytes:
    """JPEG bytes of frame ``index`` of the worker's scenario."""
    scenario: Scenario = _WORKER["scenario"]
    c = scenario.config
    return encode_jpeg(render_frame(scenario, index), c.jpeg_quality or PROFILES[c.profile].jpeg_quality or 95)


def _rendered_frames(config: ScenarioConfig, n: int, workers: int) -> Iterator[bytes]:
    if workers <= 1 or n < 8:
        _init_worker(config)
        for i in range(n):
            yield _render_frame(i)
        return
    ctx = multiprocessing.get_context("forkserver")
    with ctx.Pool(workers, initializer=_init_worker, initargs=(config,)) as pool:
        yield from pool.imap(_render_frame, range(n), chunksize=2)


# ---- messages ---------------------------------------------------------------------------------

def _ns(t: float) -> int:
    return int(round(t * 1e9))


class Messages:
    """Builds and serialises the bag's messages with a rosbags typestore."""

    def __init__(self, store):
        self.store = store
        self.T = store.types

    def header(self, t: float, frame_id: str):
        ns = _ns(t)
        return self.T["std_msgs/msg/Header"](seq=0, stamp=self.T["builtin_interfaces/msg/Time"](
            sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id=frame_id)

    def transform(self, t: float, parent: str, child: str, T: np.ndarray):
        q = matrix_to_quat(T[:3, :3])
        p = T[:3, 3]
        g = self.T
        return g["geometry_msgs/msg/TransformStamped"](
            header=self.header(t, parent), child_frame_id=child,
            transform=g["geometry_msgs/msg/Transform"](
                translation=g["geometry_msgs/msg/Vector3"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
                rotation=g["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                                          w=float(q[3]))))

    def tf(self, transforms) -> bytes:
        msg = self.T["tf2_msgs/msg/TFMessage"](transforms=list(transforms))
        return bytes(self.store.serialize_ros1(msg, "tf2_msgs/msg/TFMessage"))

    def image(self, t: float, jpeg: bytes) -> bytes:
        msg = self.T["sensor_msgs/msg/CompressedImage"](header=self.header(t, "camera"), format="jpeg",
                                                          data=np.frombuffer(jpeg, dtype=np.uint8))
        return bytes(self.store.serialize_ros1(msg, "sensor_msgs/msg/CompressedImage"))

    def imu(self, t: float, R: np.ndarray, sigma: float) -> bytes:
        """sensor_msgs/Imu at rest in orientation ``R`` (base_link in map) with roll/pitch 1-σ ``sigma`` (rad)."""
        g = self.T
        q = matrix_to_quat(R)
        a = R.T @ np.array([0.0, 0.0, 9.80665])
        cov = np.diag([sigma ** 2, sigma ** 2, 0.01]).ravel()
        msg = g["sensor_msgs/msg/Imu"](
            header=self.header(t, "base_link"),
            orientation=g["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
            orientation_covariance=cov, angular_velocity=g["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=g["geometry_msgs/msg/Vector3"](x=float(a[0]), y=float(a[1]), z=float(a[2])),
            linear_acceleration_covariance=np.eye(3).ravel() * 1e-4)
        return bytes(self.store.serialize_ros1(msg, "sensor_msgs/msg/Imu"))

    def point(self, t: float, p) -> bytes:
        msg = self.T["geometry_msgs/msg/PointStamped"](
            header=self.header(t, "map"),
            point=self.T["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2])))
        return bytes(self.store.serialize_ros1(msg, "geometry_msgs/msg/PointStamped"))


# ---- the generator ----------------------------------------------------------------------------

def _prepare_out_dir(out_dir: str, force: bool) -> None:
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as e:
        raise GenerateError(f"{out_dir}: cannot create the output directory: {e.strerror}") from None
    if not os.path.isdir(out_dir) or not os.access(out_dir, os.W_OK | os.X_OK):
        raise GenerateError(f"{out_dir}: the output directory is not writable")
    existing = [f for f in OUTPUT_FILES if os.path.exists(os.path.join(out_dir, f))]
    if existing and not force:
        raise GenerateError(f"{out_dir}: already holds {', '.join(existing)} (use --force to overwrite)")


def generate(config: ScenarioConfig, out_dir: str, progress: bool = True, force: bool = False,
             workers: int = 2) -> GeneratedScenario:
    """Render and write the scenario of ``config`` into ``out_dir`` (see the module docstring).

    Raises GenerateError for an unusable output directory or, without ``force``, existing outputs.
    """
    from rosbags.rosbag1 import Writer
    from tqdm import tqdm

    t_start = time.monotonic()
    out_dir = os.path.abspath(out_dir)
    _prepare_out_dir(out_dir, force)
    scenario = Scenario(config)
    c = scenario.config
    frame_times = scenario.frame_times
    stamps = scenario.camera_stamps
    n = frame_times.size
    odom_T_base = scenario.odom_T_base(frame_times)
    store = make_typestore()
    msgs = Messages(store)
    bag_path = os.path.join(out_dir, "scenario.bag")
    fd, tmp_bag = tempfile.mkstemp(prefix=".scenario.bag.", suffix=".tmp", dir=out_dir)
    os.close(fd)
    os.unlink(tmp_bag)  # rosbags' Writer refuses an existing file
    try:
        with Writer(tmp_bag) as writer:
            topics = dict(TOPICS, **({IMU_TOPIC: "sensor_msgs/msg/Imu"} if c.imu_rate > 0 else {}))
            conn = {topic: writer.add_connection(topic, typ, typestore=store,
                                                 latching=1 if topic == "/tf_static" else None)
                    for topic, typ in topics.items()}
            t0 = min(float(stamps[0]), float(scenario.prism.stamps[0]) if scenario.prism.stamps.size else math.inf)
            writer.write(conn["/tf_static"], _ns(t0), msgs.tf([
                msgs.transform(t0, "base_link", "camera", scenario.base_T_camera_nominal),
                msgs.transform(t0, "base_link", "prism", scenario.base_T_prism)]))
            # prism samples are merged in time order between the frames
            pending: List[Tuple[float, int]] = [(float(t), i) for i, t in enumerate(scenario.prism.stamps)]
            imu_t, imu_rp = scenario.imu_samples()
            imu_yaw = matrix_to_rpy(scenario.map_T_base(imu_t)[..., :3, :3])[2] if len(imu_t) else []
            pending += [(float(t) + c.camera_time_offset, -1 - i) for i, t in enumerate(imu_t)]  # camera clock
            heapq.heapify(pending)

            def flush(until: float) -> None:
                while pending and pending[0][0] <= until:
                    t, i = heapq.heappop(pending)
                    if i >= 0:
                        writer.write(conn["/ms60/prism"], _ns(t), msgs.point(t, scenario.prism.positions[i]))
                    else:
                        k = -1 - i
                        R = rpy_to_matrix(imu_rp[k, 0], imu_rp[k, 1], imu_yaw[k])
                        writer.write(conn[IMU_TOPIC], _ns(t), msgs.imu(t, R, math.radians(c.imu_tilt_noise_deg)))

            bar = tqdm(total=n, desc=f"render {c.width}x{c.width // 2}", unit="frame", file=sys.stderr,
                       disable=not progress, dynamic_ncols=True)
            with bar:
                for i, jpeg in enumerate(_rendered_frames(c, n, workers)):
                    s = float(stamps[i])
                    flush(s)
                    writer.write(conn["/tf"], _ns(s), msgs.tf([msgs.transform(s, "odom", "base_link",
                                                                              odom_T_base[i])]))
                    writer.write(conn["/camera/image/compressed"], _ns(s), msgs.image(s, jpeg))
                    bar.update(1)
            flush(math.inf)
        truth = Trajectory.from_transforms(frame_times, scenario.map_T_base(frame_times))
        truth_path = os.path.join(out_dir, "truth.tum")
        clock = f" + {c.clock_rate_error_ppm:g}e-6 * (t - {c.start_time:.0f})" if c.clock_rate_error_ppm else ""
        write_tum(truth_path, truth, header="base_link in map at each image's TRUE capture time (of its middle "
                                            f"row; image stamps = these + {c.camera_time_offset} s{clock})")
        markers_path = os.path.join(out_dir, "markers.yaml")
        scenario.surveyed_markers.save(markers_path)
        hidden_path = os.path.join(out_dir, "hidden.yaml")
        scenario.save_hidden(hidden_path)
        os.replace(tmp_bag, bag_path)
    finally:
        if os.path.exists(tmp_bag):
            os.unlink(tmp_bag)
    return GeneratedScenario(out_dir, bag_path, truth_path, markers_path, hidden_path, n,
                             int(scenario.prism.stamps.size), time.monotonic() - t_start)


def describe(result: GeneratedScenario, config: Optional[ScenarioConfig] = None) -> str:
    """A few lines for a terminal: what was written, how fast."""
    size_mb = os.path.getsize(result.bag) / 1e6
    fps = result.frames / result.seconds if result.seconds > 0 else float("nan")
    lines = [f"wrote {result.out_dir}/",
             f"  scenario.bag  {size_mb:.1f} MB: {result.frames} images, {result.prism_samples} prism samples",
             "  truth.tum  markers.yaml  hidden.yaml",
             f"  {result.seconds:.1f} s ({fps:.1f} frames/s)"]
    if config is not None:
        lines.insert(1, f"  seed {config.seed}, {config.duration:g} s at {config.fps:g} fps, "
                        f"{config.width}x{config.width // 2}, camera time offset {config.camera_time_offset:g} s, "
                        f"boresight error {config.boresight_deg:g} deg")
        if config.world != "open" or config.rolling_shutter_readout:
            lines.insert(2, f"  {config.world} world, rolling shutter readout "
                            f"{config.rolling_shutter_readout * 1e3:g} ms, camera clock "
                            f"{config.clock_rate_error_ppm:+g} ppm (hidden.yaml: every parameter)")
    return "\n".join(lines)
