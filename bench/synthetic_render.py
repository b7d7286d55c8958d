#!/usr/bin/env python3
"""Issue 3 figure: speed of the synthetic world at full size (3840×1920), in one run.

  render    ms/frame of render_equirect on the frames of the `bench` scenario (10 markers at
            2-12 m, 'realistic' profile without its JPEG step), one core: this renderer (edge-
            adaptive 8×8 supersampling) vs the naive one (every pixel of every marker box
            supersampled), their ratio, and the largest grey-level difference between the two
  jpeg      ms/frame of the JPEG 85 encode and kB/frame
  generate  generate() of the `bench` preset on --workers processes: frames/s end to end
            (render + JPEG + bag writing) and MB of bag per second of recording

Usage: bench/synthetic_render.py [--frames 30] [--duration 4] [--workers 2] [--width 3840]
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

from aruco_abs_orient.synthetic import render
from aruco_abs_orient.synthetic.bag import generate
from aruco_abs_orient.synthetic.scenario import PRESETS, Scenario


def frames_of(scenario, n):
    step = max(1, scenario.frame_times.size // n)
    return [(scenario.placed_markers(float(t)), float(scenario.camera_yaw(float(t))))
            for t in scenario.frame_times[::step][:n]]


def time_render(frames, width, profile, seed):
    images, t0 = [], time.perf_counter()
    for markers, yaw in frames:
        images.append(render.render_equirect(width, markers, profile=profile, seed=seed, background_yaw=yaw))
    return (time.perf_counter() - t0) / len(frames) * 1e3, images


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--frames", type=int, default=30, help="frames timed per renderer (default 30)")
    ap.add_argument("--duration", type=float, default=4.0, help="seconds of the generate() run (default 4)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--width", type=int, default=3840)
    args = ap.parse_args(argv)
    import cv2

    cv2.setNumThreads(1)
    config = dataclasses.replace(PRESETS["bench"], width=args.width, duration=max(args.duration, 1.0))
    scenario = Scenario(config)
    frames = frames_of(scenario, args.frames)
    profile = dataclasses.replace(render.PROFILES[config.profile], jpeg_quality=None)
    render.render_equirect(args.width, [], profile=profile, seed=config.seed)  # build the cached panorama

    print(f"render  ({args.frames} frames of the bench scenario, {args.width}x{args.width // 2}, "
          f"{len(scenario.markers)} markers, one core)")
    ours_ms, ours = time_render(frames, args.width, profile, config.seed)
    adaptive = render._ADAPTIVE_MIN_BIT_PX
    render._ADAPTIVE_MIN_BIT_PX = float("inf")  # naive: supersample every pixel of each marker box
    try:
        naive_ms, naive = time_render(frames, args.width, profile, config.seed)
    finally:
        render._ADAPTIVE_MIN_BIT_PX = adaptive
    diff = max(int(np.abs(a.astype(int) - b.astype(int)).max()) for a, b in zip(ours, naive))
    print(f"  adaptive supersampling  {ours_ms:7.1f} ms/frame  ({1e3 / ours_ms:5.1f} frames/s)")
    print(f"  naive supersampling     {naive_ms:7.1f} ms/frame  ({1e3 / naive_ms:5.1f} frames/s)")
    print(f"  naive / adaptive        {naive_ms / ours_ms:7.2f}x   largest grey-level difference {diff}")

    t0 = time.perf_counter()
    sizes = [len(render.encode_jpeg(img, 85)) for img in ours]
    jpeg_ms = (time.perf_counter() - t0) / len(ours) * 1e3
    print(f"jpeg    quality 85: {jpeg_ms:.1f} ms/frame, {np.mean(sizes) / 1e3:.0f} kB/frame")

    out = tempfile.mkdtemp(prefix="bench_synthetic_")
    try:
        result = generate(config, out, progress=False, workers=args.workers)
        mb = os.path.getsize(result.bag) / 1e6
    finally:
        shutil.rmtree(out, ignore_errors=True)
    print(f"generate  bench preset, {config.duration:g} s at {config.fps:g} fps on {args.workers} workers: "
          f"{result.frames} frames in {result.seconds:.1f} s = {result.frames / result.seconds:.1f} frames/s, "
          f"bag {mb / config.duration:.1f} MB per recorded second")
    return 0


if __name__ == "__main__":
    sys.exit(main())
