#!/usr/bin/env python3
"""Soak of the abs_orient node: ``--duration`` s (default 600 = 10 min) at ``--fps`` (30) on the rendered
scene of bench/node_latency.py; samples the node's memory (RSS of its process) and its latency every
``--every`` s. Bounded and local (its own master on a free port; everything stopped at the end).

    source tools/env.sh && python bench/node_soak.py --width 1920 --duration 600

Prints one line per sample and a summary: RSS growth after the first minute (flat = a few MB at most),
the latency median of the last sample vs the first (stable ≈ 1), the dropped fraction.
"""
import argparse
import sys
import time

import psutil
from _ros_harness import render_scene, run_with_node, start_feed, stop_feed


def rss_mb(pid: int) -> float:
    p = psutil.Process(pid)
    return sum(q.memory_info().rss for q in [p] + p.children(recursive=True)) / 2**20


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python bench/node_soak.py --width 1920 --duration 600")
    ap.add_argument("--width", type=int, default=1920, help="equirect width in px")
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--duration", type=float, default=600.0, help="s of soak after initialisation")
    ap.add_argument("--every", type=float, default=30.0, help="s between samples")
    args = ap.parse_args(argv)
    return run_with_node(run, args)


def run(args, ros) -> int:
    frames, base_T_prism, _ = render_scene("bench_node_soak", args.width)
    feed, mon = start_feed(ros, frames, base_T_prism, args.fps)
    samples = []
    start = time.monotonic()
    print(f"soak: {args.width}x{args.width // 2} at {args.fps:g} fps for {args.duration:g} s")
    print("   t [s]  RSS [MB]  latency median/p95 [ms]  dropped [%]  processed")
    while time.monotonic() - start < args.duration:
        time.sleep(args.every)
        if ros.node.poll() is not None:
            print("the node died", file=sys.stderr)
            return 1
        v = dict(mon.values)
        received = int(v["images received"])
        row = (time.monotonic() - start, rss_mb(ros.node.pid), float(v["latency median [ms]"]),
               float(v["latency p95 [ms]"]), 100.0 * int(v["images dropped"]) / max(received, 1),
               int(v["images processed"]))
        samples.append(row)
        print(f"  {row[0]:6.0f}  {row[1]:8.1f}  {row[2]:10.1f} / {row[3]:6.1f}  {row[4]:10.1f}  {row[5]:9d}",
              flush=True)
    stop_feed(feed)
    after_1min = next((s for s in samples if s[0] >= 60.0), samples[0])
    last = samples[-1]
    print(f"\nRSS {after_1min[1]:.1f} MB after {after_1min[0]:.0f} s -> {last[1]:.1f} MB at {last[0]:.0f} s "
          f"(growth {last[1] - after_1min[1]:+.1f} MB); latency median last/first {last[2] / samples[0][2]:.2f}; "
          f"dropped {last[4]:.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
