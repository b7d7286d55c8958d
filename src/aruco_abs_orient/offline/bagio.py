"""Reading recorded ROS 1 bags without ROS (rosbags): images, odometry tf, lever arms, prism.

A recording is one bag or several (``rosbag record --split``, a recording restarted): a list of
paths is read as one recording, its messages merged in time order (rosbags' AnyReader); gaps between
the files are gaps like any other. A first pass collects everything but the images (small: tf, tf_static, prism) into a
:class:`BagData`; images are then streamed one by one (:func:`iter_images`), so memory stays flat
with the length of the recording. Bad samples (NaN/inf in tf or prism) are skipped and counted;
a missing topic or frame is reported by name.
"""

from __future__ import annotations

import glob
import math
import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterator, List, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np

from ..errors import BagFileError
from ..transforms import make_T, quat_to_matrix
from ..tum import Trajectory

__all__ = ["BagError", "BagReadError", "BagTopics", "BagData", "read_bag_data", "iter_images", "open_reader",
           "salvage_bag", "Bags", "bag_paths", "bag_name", "expand_bags", "bags_for_shell"]

Bags = Union[str, Sequence[str]]   # one bag, or the files of one recording


def bag_paths(bags: Bags) -> List[str]:
    """The file(s) of a recording as a list."""
    if hasattr(bags, "files"):
        return list(bags.files)
    return [str(bags)] if isinstance(bags, (str, Path)) else [str(b) for b in bags]


def expand_bags(args: Sequence[str]) -> Bags:
    """Command-line bag arguments (paths or quoted globs such as ``'run_*.bag'``) → one path, or the sorted
    files of one recording; a glob that matches nothing is a BagError."""
    paths: List[str] = []
    for a in args:
        if glob.has_magic(a):
            found = sorted(glob.glob(a))
            if not found:
                raise BagError(f"{a}: no bag file matches")
            paths.extend(found)
        else:
            paths.append(a)
    return paths[0] if len(paths) == 1 else paths


def bags_for_shell(bags: Bags) -> str:
    """The recording's file(s) as shell words, for the commands the tools print."""
    if hasattr(bags, "shell_args"):
        return bags.shell_args()
    return " ".join(shlex.quote(p) for p in bag_paths(bags))


def bag_name(bags: Bags) -> str:
    """How messages name a recording: its path, or the first path and how many files follow."""
    if hasattr(bags, "name"):
        return bags.name
    paths = bag_paths(bags)
    return paths[0] if len(paths) == 1 else f"{paths[0]} (+ {len(paths) - 1} more bag(s))"



class BagError(BagFileError):
    """A bag that cannot be used: names the file and the topic/frame."""


class BagReadError(BagError):
    """A file rosbags cannot open as a bag (truncated, no index, not a bag)."""


@dataclass
class BagTopics:
    """Topic and frame names to read (doc/design.md §3 defaults)."""

    image: str = "/camera/image/compressed"
    tf: str = "/tf"
    tf_static: str = "/tf_static"
    prism: str = "/ms60/prism"
    odom_frame: str = "odom"
    base_frame: str = "base_link"
    camera_frame: str = "camera"
    prism_frame: str = "prism"
    imu: str = ""                          # sensor_msgs/Imu topic for roll/pitch (empty: none)


@dataclass
class BagData:
    """Everything of a bag but its images. Stamps in seconds of the clock that stamped them."""

    path: str
    odom: Trajectory                       # odom_T_base_link over time (camera/VO clock)
    base_T_camera: np.ndarray              # 4×4 static lever arm + mounting rotation
    base_T_prism: np.ndarray               # 4×4 static lever arm
    prism_stamps: np.ndarray               # (N,) s, total-station time
    prism_positions: np.ndarray            # (N, 3) m in map
    image_count: int
    image_format: str                      # 'compressed' or 'raw'
    start: float                           # s, first message of the bag
    end: float                             # s, last message of the bag
    skipped: Dict[str, int] = field(default_factory=dict)   # reason -> count
    warnings: List[str] = field(default_factory=list)
    imu_stamps: np.ndarray = field(default_factory=lambda: np.zeros(0))       # (K,) s, camera/VO clock
    imu_tilts: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))   # (K, 3) roll, pitch, σ in rad
    separate_clocks: bool = False          # camera and total station unsynchronised (video input)

    @property
    def image_rate(self) -> float:
        """Images per second over the odometry's span (0 when it has none)."""
        span = float(self.odom.stamps[-1] - self.odom.stamps[0]) if len(self.odom.stamps) > 1 else 0.0
        return self.image_count / span if span > 0 else 0.0


def open_reader(path: Bags):
    """An opened rosbags AnyReader over one bag or the files of one recording; a clear BagError naming
    the missing, truncated or foreign file."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    paths = [Path(p) for p in bag_paths(path)]
    if not paths:
        raise BagError("no bag file given")
    for p in paths:
        if not p.is_file():
            raise BagError(f"{p}: no such bag file")
    reader = AnyReader(paths, default_typestore=get_typestore(Stores.ROS1_NOETIC))
    try:
        reader.open()
    except Exception as e:  # rosbags raises its own classes for every kind of broken file
        raise BagReadError(f"{bag_name(path)}: cannot read the bag ({e}); a truncated bag can be repaired with "
                           "`rosbag reindex`") from None
    return reader


def _finite(*values) -> bool:
    return all(math.isfinite(v) for v in values)


def _transform_of(msg) -> Optional[np.ndarray]:
    """The 4×4 transform of a TransformStamped, None for NaN/inf or a zero quaternion."""
    t, q = msg.transform.translation, msg.transform.rotation
    if not _finite(t.x, t.y, t.z, q.x, q.y, q.z, q.w) or (q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w) < 1e-12:
        return None
    return make_T(quat_to_matrix([q.x, q.y, q.z, q.w]), [t.x, t.y, t.z])


def _stamp(header) -> float:
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


class _Collected(NamedTuple):
    """What the first pass collected: the skipped messages by reason, the odometry's stamps and transforms, the
    static transforms {(parent, child): T}, the prism's stamps and positions, the IMU's stamps and messages."""

    skipped: Dict[str, int]
    odom_t: List[float]
    odom_T: List[np.ndarray]
    statics: Dict[Tuple[str, str], np.ndarray]
    prism_t: List[float]
    prism_p: List[tuple]
    imu_t: List[float]
    imu_msgs: list


def _collect(reader, topics: BagTopics) -> _Collected:
    """The first pass over the tf, tf_static, prism and IMU messages of an open bag (what cannot be used counted
    in ``skipped`` by reason)."""
    c = _Collected({}, [], [], {}, [], [], [], [])
    wanted = [conn for conn in reader.connections if conn.topic in (topics.tf, topics.tf_static, topics.prism)
              or (topics.imu and conn.topic == topics.imu)]
    for conn, _, raw in reader.messages(connections=wanted):
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception:
            key = f"undecodable message on {conn.topic}"
            c.skipped[key] = c.skipped.get(key, 0) + 1
            continue
        if conn.topic == topics.prism:
            p = msg.point
            if not _finite(p.x, p.y, p.z):
                c.skipped["NaN/inf prism position"] = c.skipped.get("NaN/inf prism position", 0) + 1
                continue
            c.prism_t.append(_stamp(msg.header))
            c.prism_p.append((p.x, p.y, p.z))
            continue
        if topics.imu and conn.topic == topics.imu:
            c.imu_t.append(_stamp(msg.header))
            c.imu_msgs.append(msg)
            continue
        for tr in msg.transforms:
            parent, child = tr.header.frame_id.lstrip("/"), tr.child_frame_id.lstrip("/")
            T = _transform_of(tr)
            if T is None:
                key = f"NaN/inf transform {parent}->{child}"
                c.skipped[key] = c.skipped.get(key, 0) + 1
                continue
            if conn.topic == topics.tf_static:
                c.statics[(parent, child)] = T
            elif (parent, child) == (topics.odom_frame, topics.base_frame):
                c.odom_t.append(_stamp(tr.header))
                c.odom_T.append(T)
    return c


def _static(statics: Dict[Tuple[str, str], np.ndarray], child: str, topics: BagTopics, path) -> np.ndarray:
    """base_link → ``child`` from the bag's static transforms (a BagError naming those there when missing)."""
    T = statics.get((topics.base_frame, child))
    if T is None:
        have = ", ".join(f"{a}->{b}" for a, b in sorted(statics)) or "none"
        raise BagError(f"{bag_name(path)}: no static transform {topics.base_frame}->{child} on {topics.tf_static} "
                       f"(static transforms in the bag: {have})")
    return T


def _odometry(c: _Collected, topics: BagTopics, path) -> Trajectory:
    """The odometry in time order, the first of duplicate stamps kept (a BagError when there is none)."""
    if not c.odom_t:
        raise BagError(f"{bag_name(path)}: no {topics.odom_frame}->{topics.base_frame} transforms on {topics.tf}")
    order = np.argsort(c.odom_t, kind="stable")
    odom = Trajectory.from_transforms(np.asarray(c.odom_t)[order], np.asarray(c.odom_T)[order])
    keep = np.concatenate([[True], np.diff(odom.stamps) > 0])  # duplicate stamps: keep the first
    return Trajectory(odom.stamps[keep], odom.positions[keep], odom.quats[keep])


def read_bag_data(path: Bags, topics: Optional[BagTopics] = None) -> BagData:
    """First pass over a bag: odometry tf, static lever arms, prism positions, image count. ``path`` may
    also be a recording without a bag (:class:`.video.VideoRecording`): the same data from its files."""
    if hasattr(path, "read_data"):
        return path.read_data(topics)
    topics = topics or BagTopics()
    reader = open_reader(path)
    try:
        by_topic = {c.topic: c for c in reader.connections}
        present = ", ".join(sorted(by_topic)) or "none"
        image_conn = [c for c in reader.connections if c.topic == topics.image]
        if not image_conn:
            raise BagError(f"{bag_name(path)}: no image topic {topics.image} (topics in the bag: {present})")
        msgtype = image_conn[0].msgtype
        image_format = "compressed" if msgtype.endswith("CompressedImage") else "raw"
        image_count = sum(c.msgcount for c in image_conn)
        if topics.imu and topics.imu not in by_topic:
            raise BagError(f"{bag_name(path)}: no IMU topic {topics.imu} (topics in the bag: {present})")
        c = _collect(reader, topics)
        start, end = reader.start_time * 1e-9, reader.end_time * 1e-9
    finally:
        reader.close()
    warnings: List[str] = []
    odom = _odometry(c, topics, path)
    if not c.prism_t:
        warnings.append(f"{bag_name(path)}: no prism positions on {topics.prism}: yaw from markers needs the prism")
    p_order = np.argsort(c.prism_t, kind="stable")
    imu_stamps, imu_tilts = _imu_tilts(c.imu_t, c.imu_msgs, c.statics, topics, c.skipped)
    if topics.imu and not len(imu_stamps):
        warnings.append(f"{bag_name(path)}: no usable IMU sample on {topics.imu}: tilt from the markers and the "
                        "odometry")
    return BagData(
        path=bag_name(path), odom=odom, base_T_camera=_static(c.statics, topics.camera_frame, topics, path),
        base_T_prism=_static(c.statics, topics.prism_frame, topics, path),
        prism_stamps=np.asarray(c.prism_t, dtype=float)[p_order],
        prism_positions=np.asarray(c.prism_p, dtype=float).reshape(-1, 3)[p_order],
        image_count=image_count, image_format=image_format, start=start, end=end, skipped=c.skipped,
        warnings=warnings, imu_stamps=imu_stamps, imu_tilts=imu_tilts)


def _imu_tilts(stamps, msgs, statics, topics: BagTopics, skipped: Dict[str, int]):
    """(stamps (K,), (roll, pitch, σ) (K, 3) rad) of base_link from sensor_msgs/Imu messages
    (:func:`tilt.tilt_from_imu`; the IMU's mounting rotation from tf_static base_link→its frame, when
    there); unusable samples (NaN, unknown orientation while moving) are counted in ``skipped``."""
    from ..tilt import tilt_from_imu

    out_t, out = [], []
    for t, m in zip(stamps, msgs):
        T = statics.get((topics.base_frame, m.header.frame_id.lstrip("/")))
        o, a, w = m.orientation, m.linear_acceleration, m.angular_velocity
        tilt, why = tilt_from_imu([o.x, o.y, o.z, o.w], m.orientation_covariance, [a.x, a.y, a.z],
                                  m.linear_acceleration_covariance, [w.x, w.y, w.z],
                                  base_R_imu=None if T is None else T[:3, :3])
        if tilt is None:
            key = f"IMU sample without tilt ({why.lstrip('; ')})"
            skipped[key] = skipped.get(key, 0) + 1
            continue
        out_t.append(t)
        out.append(tilt)
    order = np.argsort(out_t, kind="stable")
    return np.asarray(out_t, dtype=float)[order], np.asarray(out, dtype=float).reshape(-1, 3)[order]


def iter_images(path: Bags, topics: Optional[BagTopics] = None) -> Iterator[Tuple[float, object]]:
    """Stream ``(stamp s, payload)`` of the image topic in bag order.

    The payload is JPEG/PNG ``bytes`` for CompressedImage and a uint8 array (H, W) or (H, W, 3)
    for raw Image (mono8, bgr8, rgb8); a message that cannot be decoded yields ``None``. A
    :class:`.video.VideoRecording` yields its decoded frames (grey arrays).
    """
    if hasattr(path, "iter_images"):
        yield from path.iter_images(topics)
        return
    topics = topics or BagTopics()
    reader = open_reader(path)
    try:
        conns = [c for c in reader.connections if c.topic == topics.image]
        for conn, _, raw in reader.messages(connections=conns):
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception:
                yield float("nan"), None
                continue
            stamp = _stamp(msg.header)
            if conn.msgtype.endswith("CompressedImage"):
                yield stamp, bytes(msg.data)
            else:
                yield stamp, _raw_image(msg)
    finally:
        reader.close()


def _raw_image(msg):
    channels = {"mono8": 1, "8UC1": 1, "bgr8": 3, "rgb8": 3, "8UC3": 3}.get(msg.encoding)
    if channels is None or msg.height * msg.step > len(msg.data):
        return None
    img = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(msg.height, msg.step)
    img = img[:, : msg.width * channels].reshape(msg.height, msg.width, channels)
    if msg.encoding == "rgb8":
        img = img[..., ::-1]
    return img[..., 0] if channels == 1 else np.ascontiguousarray(img)


def _fields(header: bytes) -> Dict[str, bytes]:
    out, i = {}, 0
    while i + 4 <= len(header):
        n = int.from_bytes(header[i:i + 4], "little")
        name, _, value = header[i + 4:i + 4 + n].partition(b"=")
        out[name.decode("ascii", "replace")] = value
        i += 4 + n
    return out


def _records(buf: bytes, start: int = 0):
    """(header fields, data) of the complete records of a ROS 1 bag stream; stops at a cut."""
    i = start
    while i + 4 <= len(buf):
        hlen = int.from_bytes(buf[i:i + 4], "little")
        if i + 8 + hlen > len(buf):
            return
        header = buf[i + 4:i + 4 + hlen]
        dlen = int.from_bytes(buf[i + 4 + hlen:i + 8 + hlen], "little")
        if i + 8 + hlen + dlen > len(buf):
            return
        yield _fields(header), buf[i + 8 + hlen:i + 8 + hlen + dlen]
        i += 8 + hlen + dlen


def salvage_bag(src: str, dst: str) -> Tuple[int, float]:
    """Copy the complete chunks of a truncated (unindexed) ROS 1 bag ``src`` into a new, indexed
    bag ``dst`` (rosbags writer): what `rosbag reindex` does, without ROS. Returns (messages
    kept, stamp of the last one in s). Raises BagError when nothing can be recovered."""
    import bz2

    from rosbags.rosbag1 import Writer

    with open(src, "rb") as f:
        buf = f.read()
    if not buf.startswith(b"#ROSBAG V2.0\n"):
        raise BagError(f"{src}: not a ROS 1 bag (no '#ROSBAG V2.0' header)")
    conns: Dict[int, dict] = {}
    messages = []
    for fields, data in _records(buf, 13):
        if fields.get("op") != b"\x05":  # only chunks hold messages; the index at the end is lost
            continue
        compression = fields.get("compression", b"none")
        if compression == b"bz2":
            data = bz2.decompress(data)
        elif compression != b"none":
            continue  # lz4 chunks need a library the core does not depend on
        for inner, payload in _records(data):
            op = inner.get("op")
            if op == b"\x07":
                info = _fields(payload)
                conns[int.from_bytes(inner["conn"], "little")] = {
                    "topic": inner["topic"].decode(), "type": info["type"].decode(),
                    "md5sum": info["md5sum"].decode(), "msgdef": info["message_definition"].decode(),
                    "callerid": info.get("callerid", b"").decode() or None,
                    "latching": int(info["latching"]) if info.get("latching") else None}
            elif op == b"\x02":
                t = inner["time"]
                messages.append((int.from_bytes(inner["conn"], "little"),
                                 int.from_bytes(t[:4], "little") * 10**9 + int.from_bytes(t[4:8], "little"), payload))
    messages = [m for m in messages if m[0] in conns]
    if not messages:
        raise BagError(f"{src}: truncated before its first complete chunk: nothing to recover")
    with Writer(dst) as writer:
        out = {cid: writer.add_connection(c["topic"], c["type"].replace("/", "/msg/", 1), msgdef=c["msgdef"],
                                          md5sum=c["md5sum"],
                                          callerid=c["callerid"], latching=c["latching"])
               for cid, c in conns.items()}
        for cid, stamp, payload in messages:
            writer.write(out[cid], stamp, payload)
    return len(messages), messages[-1][1] * 1e-9
