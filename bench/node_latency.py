#!/usr/bin/env python3
"""Latency of the abs_orient node at 30 fps on this machine, and the images it keeps up with.

``--world realistic`` (the default): the realistic world's recording (preset ``demo``: 3840×1920 JPEG 85 at 30
fps, 19 cm markers at 2–12 m in the hall, a 30 ms rolling shutter; ``--seconds`` long, rendered once into
.cache/bench/, or the scenario directory ``--scenario``) replayed as a user replays a recording: its own ROS
master, the ``replay`` node (``rosbag play --clock``, the player), the node (owning map->odom, the bag's time
offset, the recording's calibration made once by ``calibrate --every 3``: bench/offline.py) and the real
robot_localization EKF on ``cfg/ekf.yaml`` (fed by the node, its own map->odom broadcast switched off so that
the node's is the one measured), all on the same cores. It prints:

- images: in the bag, received by the node, processed, dropped (the node's /diagnostics at the end);
- latency from the image's stamp to map->odom: the wall time between the image's arrival here (the
  player publishes it when the bag's clock reaches its stamp) and the arrival here of the node's outputs
  for that image (``abs_orient/detections`` with its stamp: the node sends it, then map->odom, in one
  call): median, p95, max over every processed image;
- the node's stages, ms per processed image (decode in its own thread, track, solve, publish, tf wait), the
  means of its /diagnostics reports while the bag played;
- CPU of each process (node, player, EKF) in % of one core, and the load average.

``--world scene``: the rendered rostest scene (test/rt_abs_orient_scene.py: four markers 2.5–4 m away) fed
at ``--fps`` with wall-clock stamps, as a live robot; node latency (receipt → publish, its /diagnostics) and
the debug image's cost (``--debug-subscriber``: this process subscribes to ``~debug_image``).

    source tools/env.sh && python bench/node_latency.py                      # realistic world, 20 s
    source tools/env.sh && python bench/node_latency.py --scenario .cache/demo/scenario
    source tools/env.sh && python bench/node_latency.py --world scene --duration 30 --debug-subscriber

Prints one table; exit status 0 (1: the launch or the node failed, with one line). Bounded: everything it
starts is stopped at the end.
"""
import argparse
import os
import struct
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
from _ros_harness import free_port, render_scene, run_with_node, start_feed, stop_feed

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
LAUNCH = """<launch>
  <param name="use_sim_time" value="true"/>
  <node pkg="aruco_abs_orient" type="replay" name="replay" required="true" output="screen">
    <param name="bag" value="{bag}"/>
    <param name="delay" value="3.0"/>
  </node>
  <include file="$(find aruco_abs_orient)/launch/abs_orient.launch">
    <arg name="markers" value="{markers}"/>
    <arg name="time_offset" value="{offset}"/>
    <arg name="calibration" value="{calibration}"/>
    <arg name="state_file" value=""/>
    <arg name="respawn" value="false"/>
  </include>
  <include file="$(find aruco_abs_orient)/launch/ekf.launch">
    <arg name="config" value="{ekf}"/>
  </include>
</launch>
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python bench/node_latency.py --seconds 20")
    ap.add_argument("--world", choices=("realistic", "scene"), default="realistic")
    ap.add_argument("--seconds", type=float, default=20.0, help="realistic: length of the rendered recording, s")
    ap.add_argument("--scenario", help="realistic: a scenario directory (scenario.bag, markers.yaml, hidden.yaml)")
    ap.add_argument("--width", type=int, default=3840, help="scene: equirect width in px (height = width/2)")
    ap.add_argument("--fps", type=float, default=30.0, help="scene: frame rate")
    ap.add_argument("--duration", type=float, default=30.0, help="scene: s of measurement after initialisation")
    ap.add_argument("--debug-subscriber", action="store_true",
                    help="scene: subscribe to the node's ~debug_image while measuring (its cost when someone looks)")
    args = ap.parse_args(argv)
    if args.world == "realistic":
        return realistic(args)
    return run_with_node(scene, args)


# ------------------------------------------------------------------------------------------ realistic world
class Watch:
    """Wall arrival times (time.monotonic) of the images and of the node's outputs for them (by stamp, ns),
    and the node's /diagnostics reports while the bag plays."""

    def __init__(self):
        import rospy
        from diagnostic_msgs.msg import DiagnosticArray

        self.images, self.outputs, self.reports = {}, {}, []
        self.lock = threading.Lock()
        # the header stamp straight from the serialised messages: nothing of an image's 400 kB is decoded
        rospy.Subscriber("camera/image/compressed", rospy.AnyMsg, self._arrived, self.images, queue_size=100,
                         buff_size=1 << 26, tcp_nodelay=True)
        rospy.Subscriber("abs_orient/detections", rospy.AnyMsg, self._arrived, self.outputs, queue_size=100,
                         tcp_nodelay=True)
        rospy.Subscriber("/diagnostics", DiagnosticArray, self._on_diag)

    def _arrived(self, msg, times):
        now = time.monotonic()
        secs, nsecs = struct.unpack_from("<II", msg._buff, 4)  # Header: seq, stamp.secs, stamp.nsecs
        with self.lock:
            times.setdefault(secs * 10**9 + nsecs, now)

    def _on_diag(self, msg):
        for s in msg.status:
            if s.name == "abs_orient: pipeline":
                with self.lock:
                    self.reports.append({kv.key: kv.value for kv in s.values})


def realistic_scenario(args) -> str:
    if args.scenario:
        return args.scenario
    sys.path.insert(0, HERE)
    from offline import scenario  # the realistic recordings bench/offline.py renders (cached)

    return scenario(args.seconds, "demo")


def sample_cpu(root_pid: int, seen: dict) -> None:
    """Update ``seen`` (pid → [role, first CPU s, latest CPU s]) with the launch's processes: node, player,
    EKF, others (user + system CPU seconds; a process that has ended keeps its last sample)."""
    import psutil

    try:
        procs = psutil.Process(root_pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return
    for p in procs:
        try:
            cmd = " ".join(p.cmdline())
            t = p.cpu_times()
        except psutil.Error:
            continue
        role = ("node" if "__name:=abs_orient" in cmd else
                "player" if "rosbag" in cmd and " play " in cmd else
                "EKF" if "ekf_localization_node" in cmd else "others")
        seen.setdefault(p.pid, [role, t.user + t.system, 0.0])[2] = t.user + t.system


def realistic(args) -> int:
    import rospy
    import yaml

    scen = realistic_scenario(args)
    from offline import calibration

    cal = calibration(scen)
    with open(os.path.join(scen, "hidden.yaml")) as f:
        offset = float(yaml.safe_load(f)["camera_time_offset"])
    with open(os.path.join(ROOT, "cfg", "ekf.yaml")) as f:
        ekf = yaml.safe_load(f)
    ekf["publish_tf"] = False  # the node owns map->odom here: its latency is measured
    tmp = tempfile.mkdtemp(prefix="node_latency_")
    with open(os.path.join(tmp, "ekf.yaml"), "w") as f:
        yaml.safe_dump(ekf, f)
    with open(os.path.join(tmp, "bench.launch"), "w") as f:
        f.write(LAUNCH.format(bag=os.path.abspath(os.path.join(scen, "scenario.bag")),
                              markers=os.path.abspath(os.path.join(scen, "markers.yaml")), offset=offset,
                              ekf=os.path.join(tmp, "ekf.yaml"), calibration=cal))
    port = free_port()
    env = dict(os.environ, ROS_MASTER_URI=f"http://localhost:{port}", ROS_HOSTNAME="localhost",
               ROS_HOME=os.path.join(tmp, "ros_home"))
    os.environ.update(ROS_MASTER_URI=env["ROS_MASTER_URI"], ROS_HOSTNAME="localhost")
    with open(os.path.join(tmp, "launch.log"), "w") as log:
        launch = subprocess.Popen(["roslaunch", "-p", str(port), os.path.join(tmp, "bench.launch")], env=env,
                                  stdout=log, stderr=subprocess.STDOUT)
        try:
            time.sleep(2.0)
            rospy.init_node("bench_node_latency", disable_signals=True)
            watch = Watch()
            seen, load0, t0 = {}, os.getloadavg()[0], time.monotonic()
            t1 = t0
            while launch.poll() is None and time.monotonic() - t0 < 600:
                sample_cpu(launch.pid, seen)
                t1 = time.monotonic()
                time.sleep(0.5)
            load1 = os.getloadavg()[0]
        finally:
            if launch.poll() is None:
                launch.terminate()
            launch.wait(30)
    with open(os.path.join(tmp, "launch.log")) as f:
        lines = f.read().splitlines()
    summary = [ln[ln.index("replay: "):] for ln in lines if "replay: " in ln and "played" in ln]
    if not summary or not watch.reports:
        print(f"the replay did not finish (see {tmp}/launch.log)", file=sys.stderr)
        return 1
    with watch.lock:
        last = watch.reports[-1]
        lat = [1e3 * (sent - watch.images[stamp]) for stamp, sent in watch.outputs.items() if stamp in watch.images]
        reports = [r for r in watch.reports if float(r.get("rate [Hz]", 0)) > 0]
    received, processed = int(last["images received"]), int(last["images processed"])
    dropped = int(last["images dropped"])
    lat = np.array(lat) if lat else np.array([np.nan])
    stages = {}
    for r in reports:
        for k, v in r.items():
            if k.startswith("stage "):
                stages.setdefault(k[6:-5], []).append(float(v))
    wall = t1 - t0
    cpu = {k: 100.0 * sum(last_s - first for role, first, last_s in seen.values() if role == k) / wall
           for k in ("node", "player", "EKF", "others")}
    print(f"\nabs_orient node on the realistic world: {scen} (3840x1920 JPEG, 30 fps), replayed with the player and "
          f"the EKF on {os.cpu_count()} cores; load average {load0:.1f} before, {load1:.1f} after")
    print("  " + summary[-1])
    share = 100.0 * processed / max(received, 1)
    print(f"  images received by the node {received}, processed {processed} ({share:.1f} %), dropped {dropped} "
          "(the oldest, never queued)")
    print(f"  latency image stamp -> map->odom (arrival of the image here -> arrival of the node's outputs for it "
          f"here): median {np.median(lat):.1f} ms, p95 {np.percentile(lat, 95):.1f} ms, max {np.max(lat):.1f} ms, "
          f"n = {lat.size}")
    print("  node stages, ms per processed image (mean of its reports): "
          + ", ".join(f"{k} {np.mean(v):.1f}" for k, v in stages.items()))
    print("  CPU, % of one core over the replay: " + ", ".join(f"{k} {v:.0f}" for k, v in cpu.items()))
    return 0


# ------------------------------------------------------------------------------------ the rostest scene
def scene(args, ros) -> int:
    frames, base_T_prism, render_s = render_scene("bench_node_latency", args.width)
    print(f"rendered {args.width}x{args.width // 2} scene in {render_s:.1f} s "
          f"({len(frames['good']) / 1e3:.0f} kB JPEG)", flush=True)
    feed, mon = start_feed(ros, frames, base_T_prism, args.fps)
    debug_images = []
    if args.debug_subscriber:
        import rospy
        from sensor_msgs.msg import CompressedImage

        rospy.Subscriber("/abs_orient/debug_image/compressed", CompressedImage,
                         lambda m: debug_images.append(len(m.data)), queue_size=2, buff_size=1 << 24)
    time.sleep(2.0)  # let the tracker settle, then measure
    debug_before = len(debug_images)
    start_vals = dict(mon.values)
    mon.recording = True
    time.sleep(args.duration)
    mon.recording = False
    time.sleep(1.2)  # one more diagnostics report
    end_vals = dict(mon.values)
    stop_feed(feed)
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
    debug_ms = float(end_vals.get("stage debug image [ms]", "nan"))
    if args.debug_subscriber:
        drawn = len(debug_images) - debug_before
        per_drawn = debug_ms * float(end_vals["rate [Hz]"]) / (drawn / args.duration) if drawn else float("nan")
        print(f"  debug image, subscribed: {debug_ms:.2f} ms per processed frame (last second); {drawn} drawn in "
              f"{args.duration:g} s ({drawn / args.duration:.1f} Hz, "
              f"{np.mean(debug_images[debug_before:]) / 1e3 if drawn else float('nan'):.0f} kB), "
              f"about {per_drawn:.1f} ms per drawn frame")
    else:
        print(f"  debug image, nobody subscribed: {debug_ms:.3f} ms per processed frame (last second; budget 2 ms)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
