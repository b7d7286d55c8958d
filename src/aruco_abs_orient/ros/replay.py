"""Replay of a recording for ``postprocess.launch`` (node ``replay``): plays the bag with its clock,
says in one line how it ended, ends the launch quietly, and leaves a master it did not start as it was.

In: ``~bag`` (required), ``~rate``, ``~delay``, ``~loop``, ``~start``, ``~settle``, ``~node``, ``~record``,
``~recorder``. Out: ``rosbag play --clock`` of the bag (from ``~start``: the bag's static transforms before it
also published by this node, latched); at its end one line (images processed and dropped, poses
and EKF outputs counted, or why there were none) and a shutdown of its roslaunch as Ctrl-C does; exit status 1
when the run did not do its job (the node reported an error or died, the recorder stopped, no image arrived on
the node's topic); ``/use_sim_time`` deleted from a master its roslaunch did not start. ``replay
--prepare-record PATH`` creates the recorder's directory first. Every parameter and message: doc/ros_api.md.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from typing import Dict, List, Mapping, Optional, Sequence

__all__ = ["main", "summary_line", "parent_is_roslaunch", "process_parent", "prepare_record", "Watch",
           "static_transforms_before"]


def process_parent(pid: int) -> Optional[int]:
    """The parent pid of ``pid`` from /proc (None when the process does not exist here)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            stat = f.read()
    except OSError:
        return None
    return int(stat.rsplit(")", 1)[1].split()[1])


def parent_is_roslaunch(ppid: int) -> bool:
    """Whether process ``ppid`` is a roslaunch (its command line names roslaunch)."""
    try:
        with open(f"/proc/{ppid}/cmdline", "rb") as f:
            return b"roslaunch" in f.read()
    except OSError:
        return False


def summary_line(bag: str, duration: Optional[float], counts: Mapping[str, int],
                 diagnostics: Optional[Mapping[str, object]], problems: Sequence[str] = (),
                 image_topics: Sequence[str] = ()) -> str:
    """The one line that ends a replay. ``counts``: messages received on ``pose``, ``orientation``,
    ``filtered``; ``diagnostics``: the node's newest status (its key/values, ``message`` as it was while the
    bag played and ``level``), None when it never reported; ``problems``: what went wrong besides (a dead
    recorder or node); ``image_topics``: the bag's image topics (named when the node received none)."""
    head = f"replay: {os.path.basename(bag)} played to its end" + (f" ({duration:.1f} s)" if duration else "")
    if diagnostics is None:
        line = (f"{head}; abs_orient reported nothing on /diagnostics and published {counts.get('pose', 0)} poses "
                "(did it start? see its lines above)")
        return "; ".join([line] + list(problems))
    received = diagnostics.get("images received", "?")
    processed = diagnostics.get("images processed", "?")
    dropped = diagnostics.get("images dropped", 0)
    topic = diagnostics.get("image topic")
    parts = [f"abs_orient processed {processed} of {received} images" + (f" on {topic}" if topic else "")
             + (f" ({dropped} dropped while it was busy: a smaller rate:= gives it more time)"
                if dropped not in (0, "0", "?") else "")]
    parts.append(f"published {counts.get('pose', 0)} poses and {counts.get('orientation', 0)} marker yaws")
    if counts.get("filtered") is not None:
        parts.append(f"the EKF {counts['filtered']} odometry/filtered")
    line = f"{head}: " + ", ".join(parts)
    if str(received) == "0" and topic:
        line += (f"; no image arrived on {topic}: the bag's images are on "
                 f"{', '.join(image_topics) or 'no topic (no sensor_msgs/Image or CompressedImage in it)'}"
                 " (image_topic:= names the base topic)")
    if diagnostics.get("level") == "error":
        line += f"; abs_orient reports an error: {diagnostics.get('message')}"
    elif not counts.get("pose", 0):
        reason = str(diagnostics.get("message") or "")
        last = str(diagnostics.get("last error", "-"))
        if last not in ("", "-") and last not in reason:
            reason = f"{reason}; last error: {last}" if reason else last
        line += f"; no pose because: {reason or 'the node gave no reason'}"
    return "; ".join([line] + list(problems))


def prepare_record(path: str) -> int:
    """``replay --prepare-record PATH``: create the directory of the bag ``record:=`` names, print PATH (the
    launch file's parameter value); one line and 1 when it cannot be created."""
    directory = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(directory, exist_ok=True)
    except OSError as e:
        print(f"replay: record:={path}: cannot create the directory {directory}: {e.strerror}", file=sys.stderr)
        return 1
    if not os.access(directory, os.W_OK):
        print(f"replay: record:={path}: the directory {directory} is not writable", file=sys.stderr)
        return 1
    print(path, end="")
    return 0


class Watch:
    """Whether the nodes a replay depends on run: ``poll()`` (every second) asks the master for each name and
    the node itself for its pid. ``problems()``: what to say at the end (died, never started, restarted)."""

    def __init__(self, master, names: Mapping[str, str]):
        self.master = master
        self.names = dict(names)                      # role ('abs_orient', 'recorder') → node name
        self.pids: Dict[str, list] = {role: [] for role in names}
        self.alive: Dict[str, bool] = {role: False for role in names}

    def _pid(self, name: str) -> Optional[int]:
        import xmlrpc.client

        class Transport(xmlrpc.client.Transport):  # a node that does not answer within 2 s counts as gone
            def make_connection(self, host):
                conn = super().make_connection(host)
                conn.timeout = 2.0
                return conn

        try:
            uri = self.master.lookupNode(name)
            return int(xmlrpc.client.ServerProxy(uri, transport=Transport()).getPid("/replay")[2])
        except Exception:  # not registered, or registered but gone (killed without unregistering), or hung
            return None

    def poll(self) -> None:
        for role, name in self.names.items():
            pid = self._pid(name)
            self.alive[role] = pid is not None
            if pid is not None and (not self.pids[role] or self.pids[role][-1] != pid):
                self.pids[role].append(pid)

    def problems(self, record: str = "") -> List[str]:
        out = []
        for role, name in self.names.items():
            what = f"the recorder ({name})" if role == "recorder" else name
            if not self.alive[role]:
                out.append(f"{what} is not running: it died or never started (see its lines above)"
                           + (f": {record} is incomplete or missing" if role == "recorder" else ""))
            elif len(self.pids[role]) > 1:
                out.append(f"{what} was restarted {len(self.pids[role]) - 1} time(s): it died (see its lines above)")
        return out


def _master_is_ours(master) -> bool:
    """Whether the ROS master was started by the same roslaunch as this node (it ends with it)."""
    try:
        pid = int(master.getPid())
    except Exception:  # a master elsewhere, or gone
        return False
    return process_parent(pid) == os.getppid()


def _restore_clock(master, ours: bool) -> None:
    """Delete ``/use_sim_time`` from a master this launch did not start (later nodes back on the wall clock)."""
    if ours:
        return
    try:
        if master.hasParam("/use_sim_time"):
            master.deleteParam("/use_sim_time")
            print("replay: removed /use_sim_time from the master (it was running before this launch)",
                  flush=True)
    except Exception as e:  # the master went away first
        print(f"replay: could not remove /use_sim_time from the master: {e}", file=sys.stderr, flush=True)


class _Listener:
    """What the node and the EKF publish while the bag plays: the counts of ``abs_orient/pose``,
    ``abs_orient/orientation`` and ``odometry/filtered`` (None: never heard of), and the newest status of the
    node's pipeline on ``/diagnostics`` (its key/values with ``message`` and ``level``)."""

    def __init__(self, node: str):
        import rospy
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
        from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
        from nav_msgs.msg import Odometry

        self.lock = threading.Lock()
        self.counts: Dict[str, Optional[int]] = {"pose": 0, "orientation": 0, "filtered": None}
        self.diag: Dict[str, object] = {}
        self._levels = {DiagnosticStatus.OK: "ok", DiagnosticStatus.WARN: "warn", DiagnosticStatus.ERROR: "error"}
        self._status_name = f"{node.lstrip('/')}: pipeline"
        self._subs = [rospy.Subscriber("abs_orient/pose", PoseStamped, self._counter("pose"), queue_size=100),
                      rospy.Subscriber("abs_orient/orientation", PoseWithCovarianceStamped,
                                       self._counter("orientation"), queue_size=100),
                      rospy.Subscriber("odometry/filtered", Odometry, self._counter("filtered"), queue_size=100),
                      rospy.Subscriber("/diagnostics", DiagnosticArray, self._on_diagnostics, queue_size=10)]

    def _counter(self, key):
        def cb(_msg):
            with self.lock:
                self.counts[key] = (self.counts[key] or 0) + 1
        return cb

    def _on_diagnostics(self, msg) -> None:
        for s in msg.status:
            if s.name == self._status_name:
                with self.lock:
                    self.diag.clear()
                    self.diag.update({kv.key: kv.value for kv in s.values})
                    self.diag["message"] = s.message
                    self.diag["level"] = self._levels.get(s.level, "stale")

    def error_message(self) -> str:
        """The node's message when its level is error, else ''."""
        with self.lock:
            return str(self.diag.get("message", "")) if self.diag.get("level") == "error" else ""

    def playing(self) -> Dict[str, object]:
        """The node's message and level now (while the bag plays)."""
        with self.lock:
            return {k: self.diag[k] for k in ("message", "level") if self.diag.get(k)}

    def final(self, playing: Mapping[str, object]) -> Optional[Dict[str, object]]:
        """The node's status at the end: an error found in the last frames (the map check's verdict) wins over
        the state while playing (``playing``); None when it never reported."""
        with self.lock:
            diag = self.diag
            return (dict(diag) if diag.get("level") == "error" else dict(diag, **playing)) if diag else None

    def unregister(self) -> None:
        for s in self._subs:
            s.unregister()


def _play(cmd: List[str], watch: Watch, listener: _Listener):
    """(the rosbag play process, ended; why it was stopped, '' when it ran to its end or rospy shut down):
    runs ``cmd``, asks the master every second whether the watched nodes run and stops the playback when the
    node reports a configuration error (nothing will come of the rest of the bag)."""
    import rospy

    player = subprocess.Popen(cmd)
    t_play = time.monotonic()
    rospy.on_shutdown(lambda: player.poll() is None and player.send_signal(signal.SIGINT))
    next_poll = 0.0
    stopped = ""
    while player.poll() is None and not rospy.is_shutdown():
        time.sleep(0.1)
        if time.monotonic() >= next_poll:
            next_poll = time.monotonic() + 1.0
            watch.poll()
            message = listener.error_message()
            if message.startswith("configuration error"):  # nothing will come of the rest of the bag
                stopped = f"stopped after {time.monotonic() - t_play:.0f} s: abs_orient cannot run: {message}"
                player.send_signal(signal.SIGINT)
                player.wait()
    return player, stopped


def _played_to_its_end(bag: str, settle: float, watch: Watch, listener: _Listener, record: str):
    """(the replay's last line, whether the run failed) once the bag has played to its end: after ``settle`` s
    (wall clock: the sim clock stopped with the bag) for the last frames."""
    playing = listener.playing()   # the node's state while the bag played (after it: "no image for ...")
    time.sleep(settle)
    watch.poll()
    problems = watch.problems(record)
    final = listener.final(playing)
    with listener.lock:
        counts = dict(listener.counts)
    line = summary_line(bag, _bag_duration(bag), counts, final, problems, _image_topics(bag))
    failed = bool(problems) or final is None or final.get("level") == "error" or str(
        final.get("images received", "")) == "0"
    return line, failed


def main(argv=None) -> int:
    """Node entry point; returns the exit status (1: no bag, rosbag play failed, or the run did not do its
    job: the last line says why)."""
    args = sys.argv[1:] if argv is None else list(argv)
    if args[:1] == ["--prepare-record"] and len(args) == 2:
        return prepare_record(args[1])
    import rosgraph
    import rospy

    from . import exit_without_master

    exit_without_master("replay", "postprocess.launch", argv)
    rospy.init_node("replay", argv=argv)
    bag = rospy.get_param("~bag", "")
    rate = float(rospy.get_param("~rate", 1.0))
    delay = float(rospy.get_param("~delay", 2.0))
    loop = bool(rospy.get_param("~loop", False))
    start = float(rospy.get_param("~start", 0.0))
    settle = float(rospy.get_param("~settle", 2.0))
    record = str(rospy.get_param("~record", ""))
    master = rosgraph.Master(rospy.get_name())
    ours = _master_is_ours(master)
    rospy.on_shutdown(lambda: _restore_clock(master, ours))
    if not bag or not os.path.isfile(bag):
        rospy.logfatal(f"replay: no bag file {bag or '(bag:= is empty)'} (a relative bag:= is resolved against "
                       f"the directory roslaunch was started in)")
        _restore_clock(master, ours)
        return 1
    node = rospy.resolve_name(rospy.get_param("~node", "abs_orient"))
    names = {"abs_orient": node}
    if record:
        names["recorder"] = rospy.resolve_name(rospy.get_param("~recorder", "recorder"))
    watch = Watch(master, names)
    listener = _Listener(node)
    static = _publish_static_transforms(bag, start) if start > 0 else None  # latched while the bag plays
    cmd = (["rosbag", "play", "--clock", f"--rate={rate:g}", f"--delay={delay:g}", f"--start={start:g}", bag]
           + (["--loop"] if loop else []))
    player, stopped = _play(cmd, watch, listener)
    if rospy.is_shutdown():  # Ctrl-C, or a REQUIRED node died: roslaunch ends everything
        player.wait()
        return 0
    if player.returncode != 0 and not stopped:
        rospy.logfatal(f"replay: rosbag play {bag} failed (exit status {player.returncode}; its message is above)")
        return 1
    if stopped:
        line, failed = f"replay: {os.path.basename(bag)} {stopped}", True
    else:
        line, failed = _played_to_its_end(bag, settle, watch, listener, record)
    listener.unregister()
    if static is not None:
        static.unregister()
    if failed:
        rospy.logerr(line)
        return 1  # roslaunch: "REQUIRED process [replay] has died ... exit code 1", then it ends everything
    rospy.loginfo(line)
    ppid = os.getppid()
    if parent_is_roslaunch(ppid):
        os.kill(ppid, signal.SIGINT)  # end the launch as Ctrl-C does: no red "REQUIRED process has died"
        rospy.spin()
    return 0


def static_transforms_before(bag: str, start: float, topic: str = "/tf_static") -> list:
    """The static transforms that ``bag`` publishes on ``topic`` in its first ``start`` s, one per child frame
    (the last one sent for it, whichever node sent it), in the order of the frames' first appearance."""
    import rosbag
    import rospy

    with rosbag.Bag(bag) as b:
        end = rospy.Time.from_sec(b.get_start_time() + start)
        latest = {}
        for _, msg, _ in b.read_messages(topics=[topic], end_time=end):
            for tr in msg.transforms:
                latest[tr.child_frame_id] = tr
    return list(latest.values())


def _publish_static_transforms(bag: str, start: float):
    """Publish (latched) the static transforms before ``start``: ``rosbag play --start`` publishes them too, but
    a subscriber that connects while roscpp is sending them gets neither the message nor the latched copy (its
    latched copy is stored after the send is queued); rospy stores it first. The publisher, or None."""
    import rosbag
    import rospy
    from tf2_msgs.msg import TFMessage

    try:
        transforms = static_transforms_before(bag, start)
    except (rosbag.ROSBagException, OSError) as e:  # rosbag play says what is wrong with the bag
        rospy.logwarn(f"replay: could not read the static transforms of {bag}: {e}")
        return None
    if not transforms:
        return None
    pub = rospy.Publisher("/tf_static", TFMessage, queue_size=1, latch=True)
    pub.publish(TFMessage(transforms=transforms))
    return pub


def _image_topics(bag: str) -> List[str]:
    """The bag's topics of images (CompressedImage, Image); [] when it cannot be read."""
    try:
        import rosbag

        with rosbag.Bag(bag) as b:
            return sorted(t for t, info in b.get_type_and_topic_info().topics.items()
                          if info.msg_type in ("sensor_msgs/CompressedImage", "sensor_msgs/Image"))
    except Exception:
        return []


def _bag_duration(bag: str) -> Optional[float]:
    """Seconds of recording in ``bag`` (rosbag's index), None when it cannot be read."""
    try:
        import rosbag

        with rosbag.Bag(bag) as b:
            return b.get_end_time() - b.get_start_time()
    except Exception:
        return None


if __name__ == "__main__":
    sys.exit(main())
