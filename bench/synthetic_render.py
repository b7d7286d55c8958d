#!/usr/bin/env python3
"""Issue 3 figure: speed of the synthetic world at full size (3840×1920), in one run.

  render    CPU and wall ms/frame of render_equirect ('realistic' profile without its JPEG step,
            one core) on the frames of the `bench` scenario (10 markers at 2-12 m) and on a close
            scene (6 markers at 0.7-2 m): this renderer (edge-adaptive 8×8 supersampling) vs the
            naive one (every pixel of every marker box supersampled), their ratio and the largest
            grey-level difference between the two. CPU time is the figure on a loaded machine.
  jpeg      ms/frame of the JPEG 85 encode and kB/frame
  world     CPU ms/frame of a --preset scenario's frames (world.render_frame: for the realistic
            world the hall, pillars, posters, effects) plus their JPEG, and what that makes for the
            preset's full length on --workers cores (the 60 s demo must render in under 3 minutes)
  generate  generate() of --preset (default `bench`) on --workers processes: frames/s end to end
            (render + JPEG + bag writing) and MB of bag per second of recording

Usage: bench/synthetic_render.py [--frames 30] [--duration 4] [--workers 2] [--width 3840] [--preset demo]
"""
import argparse
import dataclasses
import os
import shutil
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "src"))

from aruco_abs_orient.camera import azel_to_bearing
from aruco_abs_orient.synthetic import render
from aruco_abs_orient.synthetic.bag import generate
from aruco_abs_orient.synthetic.scenario import PRESETS, Scenario
from aruco_abs_orient.synthetic.world import render_frame


def frames_of(scenario, n):
    step = max(1, scenario.frame_times.size // n)
    return [(scenario.placed_markers(float(t)), float(scenario.camera_yaw(float(t))))
            for t in scenario.frame_times[::step][:n]]


def time_render(frames, width, profile, seed):
    """(CPU ms/frame, wall ms/frame, images)."""
    images, c0, w0 = [], time.process_time(), time.perf_counter()
    for i, (markers, yaw) in enumerate(frames):
        images.append(render.render_equirect(width, markers, profile=profile, seed=seed, background_yaw=yaw,
                                             noise_seed=i))
    n = len(frames)
    return (time.process_time() - c0) / n * 1e3, (time.perf_counter() - w0) / n * 1e3, images


def close_frames(n, seed=1):
    rng = np.random.default_rng(seed)
    return [([render.facing_marker(i, 0.19, rng.uniform(0.7, 2.0) * azel_to_bearing(
        rng.uniform(-np.pi, np.pi), rng.uniform(-1.0, 1.0)), roll=rng.uniform(-0.5, 0.5)) for i in range(6)],
        float(rng.uniform(-np.pi, np.pi))) for _ in range(n)]


def compare(title, frames, width, profile, seed):
    ours_cpu, ours_wall, ours = time_render(frames, width, profile, seed)
    adaptive = render._ADAPTIVE_MIN_BIT_PX
    render._ADAPTIVE_MIN_BIT_PX = float("inf")  # naive: supersample every pixel of each marker box
    try:
        naive_cpu, naive_wall, naive = time_render(frames, width, profile, seed)
    finally:
        render._ADAPTIVE_MIN_BIT_PX = adaptive
    diff = max(int(np.abs(a.astype(int) - b.astype(int)).max()) for a, b in zip(ours, naive))
    print(f"  {title}")
    print(f"    adaptive supersampling  {ours_cpu:7.1f} ms/frame CPU ({1e3 / ours_cpu:5.1f} frames/s), "
          f"{ours_wall:7.1f} ms wall")
    print(f"    naive supersampling     {naive_cpu:7.1f} ms/frame CPU ({1e3 / naive_cpu:5.1f} frames/s), "
          f"{naive_wall:7.1f} ms wall")
    print(f"    naive / adaptive        {naive_cpu / ours_cpu:7.2f}x CPU; largest grey-level difference {diff}")
    return ours


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--frames", type=int, default=30, help="frames timed per renderer (default 30)")
    ap.add_argument("--duration", type=float, default=4.0, help="seconds of the generate() run (default 4)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--width", type=int, default=3840)
    ap.add_argument("--preset", default="bench", choices=sorted(PRESETS),
                    help="scenario of the world and generate sections (default bench: the easy world)")
    args = ap.parse_args(argv)
    import cv2

    cv2.setNumThreads(1)
    config = dataclasses.replace(PRESETS["bench"], width=args.width, duration=max(args.duration, 1.0))
    scenario = Scenario(config)
    frames = frames_of(scenario, args.frames)
    profile = dataclasses.replace(render.PROFILES[config.profile], jpeg_quality=None)
    render.render_equirect(args.width, [], profile=profile, seed=config.seed)  # build the cached panorama

    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"render  ({args.frames} frames, {args.width}x{args.width // 2}, one core)")
    ours = compare(f"bench scenario ({len(scenario.markers)} markers at 2-12 m from the track)", frames,
                   args.width, profile, config.seed)
    compare("close scene (6 markers at 0.7-2 m)", close_frames(args.frames), args.width, profile, config.seed)

    t0 = time.process_time()
    sizes = [len(render.encode_jpeg(img, 85)) for img in ours]
    jpeg_ms = (time.process_time() - t0) / len(ours) * 1e3
    print(f"jpeg    quality 85: {jpeg_ms:.1f} ms/frame CPU, {np.mean(sizes) / 1e3:.0f} kB/frame")

    full = dataclasses.replace(PRESETS[args.preset], width=args.width)
    sc = Scenario(full)
    step = max(1, sc.frame_times.size // args.frames)
    render_frame(sc, 0)  # caches
    t0 = time.process_time()
    for i in range(0, step * args.frames, step):
        render.encode_jpeg(render_frame(sc, i), full.jpeg_quality or 85)
    per = (time.process_time() - t0) / args.frames
    print(f"world   {args.preset} preset ({full.world} world, readout {full.rolling_shutter_readout * 1e3:g} ms), "
          f"{args.frames} frames: {per * 1e3:.1f} ms/frame CPU incl. JPEG; {full.duration:g} s at {full.fps:g} fps on "
          f"{args.workers} cores: {sc.frame_times.size * per / args.workers:.0f} s of rendering")

    config = dataclasses.replace(full, duration=max(args.duration, 1.0))
    out = tempfile.mkdtemp(prefix="bench_synthetic_")
    try:
        result = generate(config, out, progress=False, workers=args.workers)
        mb = os.path.getsize(result.bag) / 1e6
    finally:
        shutil.rmtree(out, ignore_errors=True)
    print(f"generate  {args.preset} preset, {config.duration:g} s at {config.fps:g} fps on {args.workers} workers: "
          f"{result.frames} frames in {result.seconds:.1f} s = {result.frames / result.seconds:.1f} frames/s, "
          f"bag {mb / config.duration:.1f} MB per recorded second")
    return 0


if __name__ == "__main__":
    sys.exit(main())
