#!/usr/bin/env python3
"""Live soak of the abs_orient node with chaos: ``--duration`` s (default 600 = 10 min) at ``--fps`` (30) of
``--width`` × width/2 (3840 × 1920) realistic frames of the rendered rostest scene (bench/node_latency.py),
with odometry and prism, while the node is SIGKILLed ``--kills`` times (started again as
launch/abs_orient.launch's ``respawn="true"`` does, after its ``respawn_delay``) and stalled ``--stalls``
times, alternately: the camera pauses 1-5 s (images stop; odometry and prism go on), or the node is frozen
(SIGSTOP, SIGCONT 0.5-2 s later). Events are at random moments (``--seed``), at least ``--gap`` s apart.
Bounded and local (its own master on a free port; everything stopped by pid at the end).

    source tools/env.sh && nice -n 10 python bench/node_soak.py                  # the 10-minute soak
    source tools/env.sh && nice -n 10 python bench/node_soak.py --duration 120 --kills 2 --stalls 4

Measured here, from outside the node (each published image's stamp against the detections the node
publishes for every image it processes, and map->odom on /tf):

- latency: image published → its ``abs_orient/detections`` received, percentiles over all processed
  images and over the steady state (images published outside an event: from 0.5 s before it to 1 s
  after its recovery);
- dropped fraction: published images without detections (overall, which includes the images sent while
  the node was dead or frozen, and in the steady state);
- memory: RSS of the node's process every ``--every`` s with the process it belongs to (and the host's
  load, the node's own processing rate); per process, from ``--settle`` s after its start (its RSS
  climbs for ~100 s at 3840 px while its allocator's pools fill), the floor and the peak of the first
  half of its samples vs the second half (flat: the same floor; the peak includes transient full-frame
  buffers, ~85 MB at 3840 px, present or not at the sample's instant);
- recoveries: kill → the first map->odom of the respawned node (split into kill → new process and new
  process → map->odom); stall end → the first detections of an image published after it, and the
  longest gap in map->odom during the stall.

- correctness: every map->odom's yaw against the scene's true map->odom (the first after each kill, and the
  largest of all).

Exit status 0 when the node recovered from every event and no map->odom was more than
``--max-yaw-error-deg`` (1°) off; 1 otherwise (or if it did not initialise).
"""
import argparse
import os
import signal
import sys
import threading
import time

import numpy as np
import psutil
from _ros_harness import render_scene, run_with_node, start_feed, stop_feed

from aruco_abs_orient.ros.conversions import transform_to_matrix
from aruco_abs_orient.transforms import wrap_angle, yaw_of

STEADY_BEFORE_S = 0.5   # images published this long before an event may be caught by it
STEADY_AFTER_S = 1.0    # and this long after its recovery still queued behind it
RECOVERY_TIMEOUT_S = 60.0


def rss_mb(pid: int) -> float:
    p = psutil.Process(pid)
    return sum(q.memory_info().rss for q in [p] + p.children(recursive=True)) / 2**20


class ImageGate:
    """Stands in for the feed's image publisher: passes images on unless ``paused`` and records each
    published image's stamp (ns) with its time.monotonic() publication."""

    def __init__(self, pub):
        self.pub = pub
        self.paused = threading.Event()
        self.lock = threading.Lock()
        self.published = []   # (monotonic s, stamp ns)

    def publish(self, msg):
        if self.paused.is_set():
            return
        t = time.monotonic()
        self.pub.publish(msg)
        with self.lock:
            self.published.append((t, msg.header.stamp.to_nsec()))


class Outputs:
    """Arrival (time.monotonic()) of every abs_orient/detections (by image stamp) and every map->odom, with
    the map->odom's yaw error (rad) against the scene's true map->odom."""

    def __init__(self):
        import rospy
        import rt_abs_orient_scene as scene  # in test/, on the path once _ros_harness is imported
        from tf2_msgs.msg import TFMessage

        from aruco_abs_orient.msg import MarkerObservations

        self.lock = threading.Lock()
        self.detections = {}   # stamp ns -> arrival s
        self.map_odom = []     # arrival s
        self.yaw_errors = []   # rad, one per map->odom
        self.true_yaw = float(yaw_of(scene.MAP_T_ODOM[:3, :3]))
        rospy.Subscriber("abs_orient/detections", MarkerObservations, self._on_det, queue_size=100)
        rospy.Subscriber("/tf", TFMessage, self._on_tf, queue_size=1000)

    def _on_det(self, msg):
        t = time.monotonic()
        with self.lock:
            self.detections.setdefault(msg.header.stamp.to_nsec(), t)

    def _on_tf(self, msg):
        t = time.monotonic()
        for tr in msg.transforms:
            if tr.header.frame_id.lstrip("/") == "map" and tr.child_frame_id.lstrip("/") == "odom":
                err = float(wrap_angle(yaw_of(transform_to_matrix(tr.transform)[:3, :3]) - self.true_yaw))
                with self.lock:
                    self.map_odom.append(t)
                    self.yaw_errors.append(err)


def schedule(args, rng):
    """Sorted (offset s from the soak's start, kind, length s): kills and alternating stalls at random
    moments, ``--gap`` s apart, in [10 s, duration - 15 s]."""
    kinds = ["kill"] * args.kills + [("pause", "freeze")[i % 2] for i in range(args.stalls)]
    n = len(kinds)
    if not n:
        return []
    span = args.duration - 25.0 - (n - 1) * args.gap
    if span < 0:
        raise SystemExit(f"--duration {args.duration:g} s is too short for {n} events {args.gap:g} s apart "
                         f"(needs {25 + (n - 1) * args.gap:g} s)")
    starts = np.sort(rng.uniform(0.0, span, n)) + 10.0 + args.gap * np.arange(n)
    rng.shuffle(kinds)
    lengths = {"kill": lambda: 0.0, "pause": lambda: float(rng.uniform(1.0, 5.0)),
               "freeze": lambda: float(rng.uniform(0.5, 2.0))}
    return [(float(t), k, lengths[k]()) for t, k in zip(starts, kinds)]


def run_events(events, t0, ros, gate, done, log):
    """Carry out ``events`` (see :func:`schedule`) from monotonic ``t0``; appends (kind, start, end, pid)."""
    for offset, kind, length in events:
        if done.wait(max(0.0, t0 + offset - time.monotonic())):
            return
        pid = ros.node.pid
        start = time.monotonic()
        if kind == "kill":
            ros.node.send_signal(signal.SIGKILL)
        elif kind == "pause":
            gate.paused.set()
            time.sleep(length)
            gate.paused.clear()
        else:
            ros.node.send_signal(signal.SIGSTOP)
            time.sleep(length)
            ros.node.send_signal(signal.SIGCONT)
        log.append((kind, start, time.monotonic(), pid))


def first_after(times, t):
    """The first of the sorted ``times`` later than ``t``, or None."""
    i = int(np.searchsorted(times, t, side="right"))
    return float(times[i]) if i < len(times) else None


def percentiles(values):
    if not len(values):
        return "none"
    p = np.percentile(values, [50, 90, 95, 99])
    return (f"p50 {p[0]:.0f}, p90 {p[1]:.0f}, p95 {p[2]:.0f}, p99 {p[3]:.0f}, max {np.max(values):.0f} ms "
            f"(n = {len(values)})")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="example: python bench/node_soak.py --duration 120 --kills 2 --stalls 4")
    ap.add_argument("--width", type=int, default=3840, help="equirect width in px (height = width/2)")
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--duration", type=float, default=600.0, help="s of soak after initialisation")
    ap.add_argument("--kills", type=int, default=4, help="SIGKILLs of the node (respawned)")
    ap.add_argument("--stalls", type=int, default=8, help="stalls: camera pauses and node freezes, alternately")
    ap.add_argument("--gap", type=float, default=15.0, help="s at least between two events")
    ap.add_argument("--every", type=float, default=10.0, help="s between memory samples")
    ap.add_argument("--settle", type=float, default=100.0, help="s after a process's start before its memory counts")
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--max-yaw-error-deg", type=float, default=1.0,
                    help="exit status 1 if any map->odom's yaw is further from the truth (as the chaos rostest)")
    args = ap.parse_args(argv)
    if min(args.kills, args.stalls) < 0 or args.duration <= 0 or args.every <= 0:
        ap.error("--kills/--stalls must be ≥ 0, --duration and --every > 0")
    return run_with_node(run, args, respawn=True)


def run(args, ros) -> int:
    rng = np.random.default_rng(args.seed)
    events = schedule(args, rng)
    frames, base_T_prism, render_s = render_scene("bench_node_soak", args.width)
    print(f"rendered {args.width}x{args.width // 2} scene in {render_s:.1f} s ({len(frames['good']) / 1e3:.0f} kB "
          f"JPEG)", flush=True)
    out = Outputs()
    feed, mon = start_feed(ros, frames, base_T_prism, args.fps)
    gate = ImageGate(feed.pub_image)
    feed.pub_image = gate
    print(f"soak: {args.width}x{args.width // 2} at {args.fps:g} fps for {args.duration:g} s; events at "
          + ", ".join(f"{t:.0f} s {k}" + (f" {L:.1f} s" if L else "") for t, k, L in events), flush=True)
    print("   t [s]    pid  RSS [MB]  images published  processed  node rate [Hz]  host load (1 min)", flush=True)
    done, log, mem = threading.Event(), [], []
    t0 = time.monotonic()
    events_thread = threading.Thread(target=run_events, args=(events, t0, ros, gate, done, log), daemon=True)
    events_thread.start()
    try:
        while time.monotonic() - t0 < args.duration:
            time.sleep(min(args.every, max(0.0, t0 + args.duration - time.monotonic())))
            node = ros.node
            try:
                rss = rss_mb(node.pid)
            except psutil.NoSuchProcess:   # killed just now: the next sample has the new process
                continue
            with gate.lock:
                stamps = [ns for _, ns in gate.published]
            with out.lock:
                processed = sum(1 for ns in stamps if ns in out.detections)
            published = len(stamps)
            mem.append((time.monotonic() - t0, node.pid, rss))
            rate = float(mon.values.get("rate [Hz]", "nan"))
            print(f"  {mem[-1][0]:6.0f}  {node.pid:6d}  {rss:8.1f}  {published:16d}  {processed:9d}  {rate:14.1f}  "
                  f"{os.getloadavg()[0]:17.1f}", flush=True)
        time.sleep(2.0)   # the last recoveries and in-flight detections
    finally:
        done.set()
        events_thread.join(10)
        stop_feed(feed)
    return report(args, ros, gate, out, log, mem, t0)


def report(args, ros, gate, out, log, mem, t0) -> int:
    with gate.lock:
        published = list(gate.published)
    with out.lock:
        detections = dict(out.detections)
        map_odom = np.array(out.map_odom)
        yaw_err_deg = np.degrees(np.abs(out.yaw_errors))
    ok = True
    print(f"\nevents ({len(log)}), times from the soak's start:")
    windows = []
    for kind, start, end, pid in log:
        if kind == "kill":
            restart = next((r for r in ros.restarts if r[0] >= start), None)
            back = first_after(map_odom, start + 0.1)   # in flight at the kill: within 0.1 s
            if back is None or back - start > RECOVERY_TIMEOUT_S:
                print(f"  {start - t0:6.1f} s  kill pid {pid}: NO map->odom after it")
                ok = False
                windows.append((start, start + RECOVERY_TIMEOUT_S))
                continue
            split = "" if restart is None else \
                f" (kill -> new process {restart[1] - start:.2f} s, new process -> map->odom {back - restart[1]:.2f} s)"
            first = yaw_err_deg[int(np.searchsorted(map_odom, back))]
            print(f"  {start - t0:6.1f} s  kill pid {pid}: recovery {back - start:.2f} s{split}; its first map->odom "
                  f"{first:.4f} deg off")
            windows.append((start, back))
        else:
            back = min((detections[ns] for t, ns in published if t > end and ns in detections), default=None)
            inside = map_odom[(map_odom >= start) & (map_odom <= end)]
            gaps = np.diff(np.concatenate([[start], inside, [end]]))
            what = f"camera paused {end - start:.1f} s" if kind == "pause" else f"node frozen {end - start:.1f} s"
            if back is None:
                print(f"  {start - t0:6.1f} s  {what}: NO image processed after it")
                ok = False
                windows.append((start, end + RECOVERY_TIMEOUT_S))
                continue
            print(f"  {start - t0:6.1f} s  {what}: first new image processed {back - end:.2f} s after its end; "
                  f"longest map->odom gap during it {gaps.max():.2f} s")
            windows.append((start, back))

    def steady(t):
        return not any(a - STEADY_BEFORE_S <= t <= b + STEADY_AFTER_S for a, b in windows)

    lat_all = np.array([1e3 * (detections[ns] - t) for t, ns in published if ns in detections])
    lat_steady = np.array([1e3 * (detections[ns] - t) for t, ns in published if ns in detections and steady(t)])
    n_steady = sum(1 for t, _ in published if steady(t))
    print(f"\nlatency, image published -> detections received (all {len(published)} published images):")
    print(f"  all processed:  {percentiles(lat_all)}")
    print(f"  steady state:   {percentiles(lat_steady)}")
    print(f"dropped: {100.0 * (1 - len(lat_all) / max(len(published), 1)):.1f} % overall (with the dead and "
          f"frozen node), {100.0 * (1 - len(lat_steady) / max(n_steady, 1)):.1f} % in the steady state "
          f"({n_steady} images)")
    print(f"memory (RSS of the node's process) per process, from {args.settle:g} s after its start (its buffers "
          "filled), first half of its samples vs second half: the floor (least) and the peak (transient "
          "full-frame buffers come and go):")
    for pid in dict.fromkeys(p for _, p, _ in mem):
        born = ros.node_started[pid] - t0
        rss = [r for t, p, r in mem if p == pid and t >= born + args.settle]
        times = [t for t, p, _ in mem if p == pid and t >= born + args.settle]
        if len(rss) < 4:
            print(f"  pid {pid} (started at {born:.0f} s): too short-lived for a figure")
            continue
        a, b = rss[: len(rss) // 2], rss[len(rss) // 2:]
        print(f"  pid {pid} (started at {born:.0f} s), {times[0]:.0f}-{times[-1]:.0f} s: floor {min(a):.1f} -> "
              f"{min(b):.1f} MB ({min(b) - min(a):+.1f}), peak {max(a):.1f} -> {max(b):.1f} MB "
              f"({max(b) - max(a):+.1f})")
    print(f"recovered from {sum(1 for a, b in windows if b - a < RECOVERY_TIMEOUT_S)} of {len(log)} events")
    worst = float(yaw_err_deg.max()) if len(yaw_err_deg) else float("nan")
    print(f"map->odom yaw vs the scene's truth, all {len(yaw_err_deg)} sent: median "
          f"{float(np.median(yaw_err_deg)):.4f} deg, max {worst:.4f} deg (limit {args.max_yaw_error_deg:g})")
    return 0 if ok and worst <= args.max_yaw_error_deg else 1


if __name__ == "__main__":
    sys.exit(main())
