#!/usr/bin/env python3
"""Offline throughput and memory: the real-time factor of `aruco-abs-orient process` on 30 fps
3840x1920 JPEG bags, and its peak memory for two bag lengths (it must stay flat), in one run; beside
each bag the same recording as a video (mp4v MP4 + VO trajectory + prism CSV, `process --video`).

    python bench/offline.py                    # 30 s and 120 s bags (rendered once, cached)
    python bench/offline.py --durations 10 30  # quicker

Each run is a separate process (its peak RSS is its own); the bags are rendered by the synthetic
generator into .cache/bench/ and reused, their videos written by `synthetic.export` beside them.
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


def video_inputs(scen: str) -> list:
    """``process`` options of the scenario as a video (written once by ``synthetic.export``)."""
    from aruco_abs_orient.synthetic.export import export_video

    out = os.path.join(scen, "video")
    if not os.path.exists(os.path.join(out, "truth.tum")):
        print(f"writing {scen} as video.mp4 + vo.tum + prism.csv (once)", file=sys.stderr)
        export_video(scen, out)
    return ["--video", os.path.join(out, "video.mp4"), "--trajectory", os.path.join(out, "vo.tum"), "--prism",
            os.path.join(out, "prism.csv"), "--lever-arms", os.path.join(out, "lever_arms.yaml")]


def run(scen: str, out: str, video: bool = False) -> dict:
    import yaml

    with open(os.path.join(scen, "hidden.yaml")) as f:
        hidden = yaml.safe_load(f)
    offset = hidden["camera_time_offset"]
    inputs = [os.path.join(scen, "scenario.bag")]
    if video:  # the video's clock: 0 = the first frame's camera stamp (start_time + offset)
        inputs = video_inputs(scen)
        offset = -float(hidden["config"]["start_time"])
    cmd = [sys.executable, "-m", "aruco_abs_orient.offline.cli", "process", *inputs,
           "--markers", os.path.join(scen, "markers.yaml"), "--out", out, "--time-offset", repr(offset), "--quiet"]
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
        for video in (False, True):
            out = os.path.join(ROOT, ".cache", "bench", f"offline_{d:g}s_{'video' if video else 'bag'}_out")
            rows.append((d, "video" if video else "bag", run(scen, out, video)))
    print("\noffline processing, 3840x1920 at 30 fps: JPEG bag / mp4v video (this machine, 2 cores)")
    print(f"{'length':>6} {'input':>6} {'frames':>7} {'wall s':>8} {'x real time':>12} {'peak RSS MB':>12}  "
          "ms/frame (decode/detect/solve)")
    for d, kind, r in rows:
        ms = "/".join(f"{r['ms'].get(k, 0.0):.1f}" for k in ("decode", "detect", "solve"))
        print(f"{d:>5g}s {kind:>6} {r['frames']:>7} {r['wall_s']:>8.1f} {r['rtf']:>12.2f} {r['peak_rss_mb']:>12.0f}  "
              f"{ms}")
    for kind in ("bag", "video"):
        peaks = [r["peak_rss_mb"] for _, k, r in rows if k == kind]
        if len(peaks) >= 2:
            print(f"peak memory ratio, {kind}, {max(a.durations):g} s / {min(a.durations):g} s: "
                  f"{peaks[-1] / peaks[0]:.2f} (flat = 1)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
