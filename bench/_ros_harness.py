"""The ROS scaffold the node benches share (bench/node_latency.py, bench/node_soak.py); not a bench.

A private ROS master on a free port, the lever-arm static tfs and the abs_orient node on the marker map
of the rendered rostest scene (test/rt_abs_orient_scene.py), a feed of that scene at a frame rate and a
monitor of the node's /diagnostics and detections; everything it starts is stopped by pid at the end.
With ``respawn``, a node that dies is started again the way roslaunch does for launch/abs_orient.launch
(``respawn="true"``: its ``respawn_delay`` after the death is noticed, polled every 0.1 s).
"""
import os
import socket
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ET

HERE = os.path.dirname(os.path.abspath(__file__))
TEST_DIR = os.path.join(HERE, "..", "test")
sys.path.insert(0, TEST_DIR)

SCENE_MARKERS = os.path.join(TEST_DIR, "abs_orient_scene_markers.yaml")
NODE_LAUNCH = os.path.join(HERE, "..", "launch", "abs_orient.launch")
INIT_TIMEOUT_S = 60.0


class BenchError(RuntimeError):
    """The node did not come up (the message is the bench's one-line report)."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def launch_respawn_delay(path=NODE_LAUNCH) -> float:
    """The abs_orient node's ``respawn_delay`` (s) in launch/abs_orient.launch (roslaunch's default 0 when
    it sets none)."""
    node = ET.parse(path).getroot().find("node[@name='abs_orient']")
    if node is None:
        raise BenchError(f"{path}: no <node name=\"abs_orient\">")
    return float(node.get("respawn_delay", 0.0))


class RosProcesses:
    """A private master + static tfs + the node, stopped (by pid) on exit. With ``respawn_delay`` (s)
    the node is started again that long after it died (as roslaunch's respawn); :attr:`restarts`
    lists ``(death noticed, restarted, new pid)`` and :attr:`node_started` maps each node process's pid to
    its start, in time.monotonic() s."""

    def __init__(self, node_params, respawn_delay=None):
        port = free_port()
        os.environ["ROS_MASTER_URI"] = f"http://localhost:{port}"
        os.environ.setdefault("ROS_HOSTNAME", "localhost")
        self.procs = []
        log = subprocess.DEVNULL
        self.procs.append(subprocess.Popen(["rosmaster", "--core", "-p", str(port)], stdout=log, stderr=log))
        time.sleep(1.5)
        for args in (["0.10", "0.0", "0.50", "0", "0", "0", "base_link", "camera"],
                     ["-0.05", "0.0", "0.70", "0", "0", "0", "base_link", "prism"]):
            self.procs.append(subprocess.Popen(["rosrun", "tf2_ros", "static_transform_publisher"] + args,
                                               stdout=log, stderr=log))
        params = [f"_{k}:={v}" for k, v in node_params.items()]
        self.node_cmd = [os.path.join(HERE, "..", "scripts", "abs_orient")] + params
        self.node = subprocess.Popen(self.node_cmd, stdout=log, stderr=subprocess.STDOUT)
        self.node_started = {self.node.pid: time.monotonic()}
        self.restarts = []
        self._stopping = threading.Event()
        self._supervisor = None
        if respawn_delay is not None:
            self._supervisor = threading.Thread(target=self._supervise, args=(respawn_delay,), daemon=True)
            self._supervisor.start()

    def _supervise(self, delay):
        while not self._stopping.wait(0.1):
            if self.node.poll() is None:
                continue
            died = time.monotonic()
            if self._stopping.wait(delay):
                return
            self.node = subprocess.Popen(self.node_cmd, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
            self.node_started[self.node.pid] = time.monotonic()
            self.restarts.append((died, time.monotonic(), self.node.pid))

    def stop(self):
        self._stopping.set()
        if self._supervisor is not None:
            self._supervisor.join(5)
        for p in [self.node] + list(reversed(self.procs)):
            if p.poll() is None:
                p.terminate()
        for p in [self.node] + self.procs:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()


class Monitor:
    """Collects /diagnostics values of the node and end-to-end latencies of its detections."""

    def __init__(self, feed):
        import rospy
        from diagnostic_msgs.msg import DiagnosticArray

        from aruco_abs_orient.msg import MarkerObservations

        self.feed = feed
        self.lock = threading.Lock()
        self.values = {}
        self.e2e_ms = []
        self.recording = False
        rospy.Subscriber("/diagnostics", DiagnosticArray, self._on_diag)
        rospy.Subscriber("abs_orient/detections", MarkerObservations, self._on_det, queue_size=100)

    def _on_diag(self, msg):
        for s in msg.status:
            if s.name == "abs_orient: pipeline":
                with self.lock:
                    self.values = {kv.key: kv.value for kv in s.values}
                    self.values["_sent"] = self.feed.sent  # images sent when this report arrived

    def _on_det(self, msg):
        sent = self.feed.sent_wall.get(msg.header.stamp.to_nsec())
        if sent is not None and self.recording:
            with self.lock:
                self.e2e_ms.append(1e3 * (time.monotonic() - sent))


def run_with_node(run, args, respawn=False) -> int:
    """Start the processes (with ``respawn``: the node respawned as abs_orient.launch does), return
    ``run(args, ros)`` (an exit status), stop them; a :class:`BenchError` becomes its message on stderr
    and status 1."""
    try:
        ros = RosProcesses({"markers": SCENE_MARKERS}, launch_respawn_delay() if respawn else None)
    except BenchError as e:
        print(e, file=sys.stderr)
        return 1
    try:
        return run(args, ros)
    except BenchError as e:
        print(e, file=sys.stderr)
        return 1
    finally:
        ros.stop()


def render_scene(node_name, width):
    """Join ROS as ``node_name``, read the lever arms from tf and render the scene's frames at
    ``width`` px (equirect, height width/2). Returns ``(frames, base_T_prism, render_s)``, the
    last the rendering's wall time (s)."""
    import rospy
    import rt_abs_orient_scene as scene
    import tf2_ros

    rospy.init_node(node_name, disable_signals=True)
    tf = tf2_ros.Buffer(debug=False)
    tf2_ros.TransformListener(tf)
    base_T_camera, base_T_prism = scene.lever_arms(tf)
    t0 = time.perf_counter()
    frames = scene.render_frames(base_T_camera, width=width)
    return frames, base_T_prism, time.perf_counter() - t0


def start_feed(ros, frames, base_T_prism, fps):
    """Feed ``frames`` at ``fps`` with odometry and prism and watch the node until it reports
    itself initialised (at most INIT_TIMEOUT_S s). Returns ``(feed, monitor)``; raises
    :class:`BenchError` if the node dies or does not initialise."""
    import rt_abs_orient_scene as scene

    feed = scene.Feed(frames, base_T_prism, rate=fps)
    mon = Monitor(feed)
    feed.start()
    deadline = time.monotonic() + INIT_TIMEOUT_S
    while time.monotonic() < deadline and mon.values.get("initialised") != "True":
        if ros.node.poll() is not None:
            stop_feed(feed)
            raise BenchError("the node died")
        time.sleep(0.2)
    if mon.values.get("initialised") != "True":
        stop_feed(feed)
        raise BenchError(f"the node did not initialise within {INIT_TIMEOUT_S:g} s")
    return feed, mon


def stop_feed(feed):
    feed.stop.set()
    feed.join(5)
