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
- dropped fraction: images the node replaced in its one-slot mailbox before processing them;
- the debug image's cost per processed frame (the node's ``stage debug image [ms]``): nobody subscribes to
  ``~debug_image`` (the default: one check of the subscriber count), or, with ``--debug-subscriber``, this
  process subscribes (then a frame is drawn and JPEG-encoded at ``~debug_rate`` Hz; the cost of one drawn
  frame is the mean per processed frame times the processing rate over the drawing rate).

    source tools/env.sh && python bench/node_latency.py --width 3840 --fps 30 --duration 30
    source tools/env.sh && python bench/node_latency.py --width 3840 --fps 30 --duration 30 --debug-subscriber

Prints one table; exit status 0. Bounded: everything it starts is stopped at the end.
"""
import argparse
import sys
import time

import numpy as np
from _ros_harness import render_scene, run_with_node, start_feed, stop_feed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python bench/node_latency.py --width 3840 --fps 30 --duration 30")
    ap.add_argument("--width", type=int, default=3840, help="equirect width in px (height = width/2)")
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--duration", type=float, default=30.0, help="s of measurement after initialisation")
    ap.add_argument("--debug-subscriber", action="store_true",
                    help="subscribe to the node's ~debug_image while measuring (its cost when someone looks)")
    args = ap.parse_args(argv)
    return run_with_node(run, args)


def run(args, ros) -> int:
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
