"""The ROS scaffold the node benches share (bench/node_latency.py, bench/node_soak.py); not a bench.

A private ROS master on a free port, the lever-arm static tfs and the abs_orient node on the marker map
of the rendered rostest scene (test/rt_abs_orient_scene.py), a feed of that scene at a frame rate and a
monitor of the node's /diagnostics and detections; everything it starts is stopped by pid at the end.
"""
import os
import socket
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
TEST_DIR = os.path.join(HERE, "..", "test")
sys.path.insert(0, TEST_DIR)

SCENE_MARKERS = os.path.join(TEST_DIR, "abs_orient_scene_markers.yaml")
INIT_TIMEOUT_S = 60.0


class BenchError(RuntimeError):
    """The node did not come up (the message is the bench's one-line report)."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class RosProcesses:
    """A private master + static tfs + the node, stopped (by pid) on exit."""

    def __init__(self, node_params):
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
        script = os.path.join(HERE, "..", "scripts", "abs_orient")
        self.node = subprocess.Popen([script] + params, stdout=log,
                                     stderr=subprocess.STDOUT)
        self.procs.append(self.node)

    def stop(self):
        for p in reversed(self.procs):
            if p.poll() is None:
                p.terminate()
        for p in self.procs:
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


def run_with_node(run, args) -> int:
    """Start the processes, return ``run(args, ros)`` (an exit status), stop them; a
    :class:`BenchError` becomes its message on stderr and status 1."""
    ros = RosProcesses({"markers": SCENE_MARKERS})
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
