#!/usr/bin/env python3
"""Offline throughput and memory: the real-time factor of `aruco-abs-orient process` on 30 fps
3840x1920 JPEG bags, and its peak memory for two bag lengths (it must stay flat), in one run.

    python bench/offline.py                    # 30 s and 120 s bags (rendered once, cached)
    python bench/offline.py --durations 10 30  # quicker

Each run is a separate process (its peak RSS is its own); the bags are rendered by the synthetic
generator into .cache/bench/ and reused.
"""
import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import replace

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def scenario(duration: float) -> str:
    from aruco_abs_orient.synthetic.bag import generate
    from aruco_abs_orient.synthetic.scenario import PRESETS

    out = os.path.join(ROOT, ".cache", "bench", f"offline_{duration:g}s")
    if not os.path.exists(os.path.join(out, "scenario.bag")):
        print(f"rendering a {duration:g} s 3840x1920 30 fps scenario into {out} (once)", file=sys.stderr)
        generate(replace(PRESETS["bench"], duration=duration), out, progress=True, force=True)
    return out


def run(scen: str, out: str) -> dict:
    import yaml

    with open(os.path.join(scen, "hidden.yaml")) as f:
        offset = yaml.safe_load(f)["camera_time_offset"]
    cmd = [sys.executable, "-m", "aruco_abs_orient.offline.cli", "process", os.path.join(scen, "scenario.bag"),
           "--markers", os.path.join(scen, "markers.yaml"), "--out", out, "--time-offset", str(offset), "--quiet"]
    import psutil

    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
    peak = 0
    ps = psutil.Process(proc.pid)
    while proc.poll() is None:  # sample the child's resident memory (ru_maxrss would mix the runs)
        try:
            peak = max(peak, ps.memory_info().rss)
        except psutil.NoSuchProcess:
            break
        time.sleep(0.05)
    wall = time.perf_counter() - t0
    if proc.returncode:
        raise SystemExit(f"process failed ({proc.returncode}): {' '.join(cmd)}")
    with open(os.path.join(out, "summary.json")) as f:
        summary = json.load(f)
    return {"bag_s": summary["bag_duration_s"], "frames": summary["frames"], "wall_s": wall,
            "rtf": summary["bag_duration_s"] / wall, "peak_rss_mb": peak / 2**20,
            "ms": summary["mean_ms_per_frame"], "modes": summary["search_modes"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--durations", type=float, nargs="+", default=[30.0, 120.0], help="bag lengths, s")
    a = ap.parse_args()
    rows = []
    for d in sorted(a.durations):
        scen = scenario(d)
        rows.append((d, run(scen, os.path.join(ROOT, ".cache", "bench", f"offline_{d:g}s_out"))))
    print("\noffline processing, 3840x1920 JPEG at 30 fps (this machine, 2 cores)")
    print(f"{'bag':>6} {'frames':>7} {'wall s':>8} {'x real time':>12} {'peak RSS MB':>12}  "
          "ms/frame (decode/detect/solve)")
    for d, r in rows:
        ms = "/".join(f"{r['ms'].get(k, 0.0):.1f}" for k in ("decode", "detect", "solve"))
        print(f"{d:>5g}s {r['frames']:>7} {r['wall_s']:>8.1f} {r['rtf']:>12.2f} {r['peak_rss_mb']:>12.0f}  {ms}")
    if len(rows) >= 2:
        print(f"peak memory ratio {rows[-1][0]:g} s / {rows[0][0]:g} s bag: "
              f"{rows[-1][1]['peak_rss_mb'] / rows[0][1]['peak_rss_mb']:.2f} (flat = 1)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
