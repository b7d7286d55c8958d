#!/usr/bin/env python3
"""Latency of the abs_orient node at 30 fps on this machine: image receipt → publish, and dropped frames.

Starts its own ROS master (a free port), the lever-arm static tfs and the node, then feeds the rendered
scene of the rostests (test/rt_abs_orient_scene.py: four markers 2.5–4 m away, realistic JPEG frames) at
``--fps`` with odometry and prism, wall-clock stamps, like a live robot. Once the node has initialised
(tracking mode), it measures for ``--duration`` s:

- node latency: receipt of the image in the node → map->odom/detections published (the node's own
  clock, reported on /diagnostics: median and p95 over its last 600 frames);
- end-to-end latency: image published here → ``abs_orient/detections`` with that stamp received here
  (adds two local transports and the JPEG hand-over);
- dropped fraction: images the node replaced in its one-slot mailbox before processing them.

    source tools/env.sh && python bench/node_latency.py --width 3840 --fps 30 --duration 30

Prints one table; exit status 0. Bounded: everything it starts is stopped at the end.
"""
import argparse
import os
import socket
import subprocess
import sys
import threading
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "test"))


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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python bench/node_latency.py --width 3840 --fps 30 --duration 30")
    ap.add_argument("--width", type=int, default=3840, help="equirect width in px (height = width/2)")
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--duration", type=float, default=30.0, help="s of measurement after initialisation")
    args = ap.parse_args(argv)
    ros = RosProcesses({"markers": os.path.join(HERE, "..", "test", "abs_orient_scene_markers.yaml")})
    try:
        return run(args, ros)
    finally:
        ros.stop()


def run(args, ros) -> int:
    import rospy
    import rt_abs_orient_scene as scene
    import tf2_ros

    rospy.init_node("bench_node_latency", disable_signals=True)
    tf = tf2_ros.Buffer(debug=False)
    tf2_ros.TransformListener(tf)
    base_T_camera, base_T_prism = scene.lever_arms(tf)
    t0 = time.perf_counter()
    frames = scene.render_frames(base_T_camera, width=args.width)
    print(f"rendered {args.width}x{args.width // 2} scene in {time.perf_counter() - t0:.1f} s "
          f"({len(frames['good']) / 1e3:.0f} kB JPEG)", flush=True)
    feed = scene.Feed(frames, base_T_prism, rate=args.fps)
    mon = Monitor(feed)
    feed.start()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and mon.values.get("initialised") != "True":
        if ros.node.poll() is not None:
            print("the node died", file=sys.stderr)
            return 1
        time.sleep(0.2)
    if mon.values.get("initialised") != "True":
        print("the node did not initialise within 60 s", file=sys.stderr)
        return 1
    time.sleep(2.0)  # let the tracker settle, then measure
    start_vals = dict(mon.values)
    mon.recording = True
    time.sleep(args.duration)
    mon.recording = False
    time.sleep(1.2)  # one more diagnostics report
    end_vals = dict(mon.values)
    feed.stop.set()
    feed.join(5)
    received = int(end_vals["images received"]) - int(start_vals["images received"])
    dropped = int(end_vals["images dropped"]) - int(start_vals["images dropped"])
    processed = int(end_vals["images processed"]) - int(start_vals["images processed"])
    e2e = np.array(mon.e2e_ms) if mon.e2e_ms else np.array([np.nan])
    print(f"\nabs_orient node, {args.width}x{args.width // 2} JPEG at {args.fps:g} fps, {args.duration:g} s, "
          f"tracking 4 markers")
    sent = end_vals["_sent"] - start_vals["_sent"]
    print(f"  images sent {sent}, received by the node {received}, processed {processed}, "
          f"dropped {dropped} ({100.0 * dropped / max(received, 1):.1f} %)")
    print(f"  node latency (receipt -> publish), last 600 frames: "
          f"median {float(end_vals['latency median [ms]']):.1f} ms, p95 {float(end_vals['latency p95 [ms]']):.1f} ms")
    stages = [f"{k[6:-5]} {end_vals[k]}" for k in end_vals if k.startswith("stage ")]
    print("  node stages (last second), mean ms: " + ", ".join(stages))
    print(f"  end-to-end (publish here -> detections here): median {np.median(e2e):.1f} ms, "
          f"p95 {np.percentile(e2e, 95):.1f} ms, n = {len(mon.e2e_ms)}")
    print(f"  processing rate {float(end_vals['rate [Hz]']):.1f} Hz; budget 50 ms at 30 fps")
    return 0


if __name__ == "__main__":
    sys.exit(main())
