#!/usr/bin/env python3
"""Offline throughput and memory: the real-time factor of `aruco-abs-orient process` on 30 fps
3840x1920 JPEG bags, and its peak memory for two bag lengths (it must stay flat), in one run; beside
each bag the same recording as a video (mp4v MP4 + VO trajectory + prism CSV, `process --video`).

    python bench/offline.py                    # 30 s and 120 s bags (rendered once, cached)
    python bench/offline.py --durations 10 30  # quicker
    python bench/offline.py --speed            # only the speed section (realistic world, below)

The speed section (issue 17), on the realistic world with its 30 ms rolling shutter (preset `demo`,
--speed-seconds long, or the scenario directory --speed-scenario), calibrated as a user would (`calibrate
--every 3`, once: :func:`calibration`), every figure measured in this one run
(the machine is shared: compare the ratios, not the absolute figures of two runs):
  process     `process` as shipped (one OpenBLAS thread: aruco_abs_orient.offline; recovery searches
              backing off) against the same as before issue 17's speed work (OpenBLAS's default threads,
              one per core; tracking.lost_backoff_max_frames 0; only the JPEG decoding in two threads
              instead of one stays), and the naive way: every frame decoded whole and searched whole
              (MarkerDetector.detect, no tracking) on --naive-frames frames; frames/s, x real time at
              the bag's frame rate, CPU ms per frame, the heading RMSE of both runs against the
              scenario's truth.tum (`evaluate --reference`: the speed must not cost accuracy), and the
              x real time the CPU seconds make on free cores (summary.json's cpu_time_s: the wall
              time is about max(the pipeline thread's CPU, all threads' CPU / cores));
  decode      `process` as shipped, decoding only the image rows tracking reads (tracking.decode_rows), against
              the same with whole frames decoded (as before: decode_rows false), in the same run: frames/s,
              CPU, the heading RMSE (the trajectories must be the same, byte for byte: checked), the share
              of the rows decoded, the frames decoded in part and those a search then decoded whole;
  render      CPU seconds per frame of the demo preset's frames (world.render_frame + JPEG, one OpenCV
              thread as in the generator's workers) and the 60 s demo's rendering time that makes on
              2 workers (budget: 3 minutes).

Each run is a separate process (its peak RSS is its own); the bags are rendered by the synthetic
generator into .cache/bench/ and reused, their videos written by `synthetic.export` beside them.
"""
import argparse
import contextlib
import filecmp
import json
import os
import resource
import subprocess
import sys
import time
from dataclasses import replace

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def scenario(duration: float, preset: str = "bench") -> str:
    """The ``preset`` scenario (``bench``: the easy world at 3840×1920, 30 fps; ``demo``: the realistic world
    with its rolling shutter), ``duration`` s long, rendered once into .cache/bench/."""
    from aruco_abs_orient.synthetic.bag import generate
    from aruco_abs_orient.synthetic.scenario import PRESETS

    name = "offline" if preset == "bench" else f"offline_{preset}"
    out = os.path.join(ROOT, ".cache", "bench", f"{name}_{duration:g}s")
    if not os.path.exists(os.path.join(out, "scenario.bag")):
        print(f"rendering a {duration:g} s scenario (preset {preset}) into {out} (once)", file=sys.stderr)
        generate(replace(PRESETS[preset], duration=duration), out, progress=True, force=True)
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


def calibration(scen: str) -> str:
    """The calibration file of scenario directory ``scen`` as its user makes it (`calibrate --every 3` at the
    truth's time offset), made once into .cache/bench/calibrated/ (keyed by the bag's path, size and time): the
    realistic world's camera is mounted 0.3° off and has two lenses, and a user processes and runs the node with
    its calibration (without it the ROI views miss and the tracker falls back to full-frame searches)."""
    import hashlib

    import _workflow

    bag = os.path.join(scen, "scenario.bag")
    stamp = f"{os.path.abspath(bag)} {os.path.getsize(bag)} {os.path.getmtime(bag)}"
    path = os.path.join(ROOT, ".cache", "bench", "calibrated", f"{os.path.basename(os.path.normpath(scen))}_"
                        f"{hashlib.sha1(stamp.encode()).hexdigest()[:10]}.yaml")
    if not os.path.exists(path):
        print(f"calibrating {scen} into {path} (once)", file=sys.stderr)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        _workflow.cli("calibrate", bag, "--markers", os.path.join(scen, "markers.yaml"), "--time-offset",
                      repr(_workflow.hidden_of(scen)["camera_time_offset"]), "--every", 3, "--quiet", "--out", path)
    return path


def run(scen: str, out: str, video: bool = False, env: dict = None, extra: tuple = ()) -> dict:
    """`process` of scenario directory ``scen`` into ``out`` in a child process (``env``: changes to its
    environment; ``extra``: more options): frames, wall and CPU seconds, real-time factor, peak memory,
    ms/frame by stage."""
    import yaml

    with open(os.path.join(scen, "hidden.yaml")) as f:
        hidden = yaml.safe_load(f)
    offset = hidden["camera_time_offset"]
    inputs = [os.path.join(scen, "scenario.bag")]
    if video:  # the video's clock: 0 = the first frame's camera stamp (start_time + offset)
        inputs = video_inputs(scen)
        offset = -float(hidden["config"]["start_time"])
    cmd = [sys.executable, "-m", "aruco_abs_orient.offline.cli", "process", *inputs,
           "--markers", os.path.join(scen, "markers.yaml"), "--out", out, "--time-offset", repr(offset), "--quiet",
           *extra]
    import psutil

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, env=None if env is None else {**os.environ, **env})
    peak = 0
    ps = psutil.Process(proc.pid)
    while proc.poll() is None:  # sample the child's resident memory (ru_maxrss would mix the runs)
        try:
            peak = max(peak, ps.memory_info().rss)
        except psutil.NoSuchProcess:
            break
        time.sleep(0.05)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode:
        raise SystemExit(f"process failed ({proc.returncode}): {' '.join(cmd)}")
    with open(os.path.join(out, "summary.json")) as f:
        summary = json.load(f)
    return {"bag_s": summary["bag_duration_s"], "frames": summary["frames"], "wall_s": wall,
            "rtf": summary["bag_duration_s"] / wall, "peak_rss_mb": peak / 2**20,
            "cpu_s": (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime),
            "ms": summary["mean_ms_per_frame"], "modes": summary["search_modes"],
            # the wall time on free cores: the pipeline thread's CPU, or all threads' CPU shared by the cores
            "free_s": max(summary["cpu_time_s"]["pipeline_thread"],
                          summary["cpu_time_s"]["all_threads"] / (os.cpu_count() or 2))}


def heading_rmse(scen: str, out: str) -> float:
    """Heading RMSE (degrees) of the run in ``out`` against the scenario's truth (`evaluate --reference`)."""
    subprocess.run([sys.executable, "-m", "aruco_abs_orient.offline.cli", "evaluate", out, "--reference",
                    os.path.join(scen, "truth.tum"), "--out", out + "_eval"], stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL, check=True)
    with open(os.path.join(out + "_eval", "report.json")) as f:
        return float(json.load(f)["heading_ape"]["rmse_deg"])


def naive(scen: str, frames: int) -> dict:
    """The naive way in this process: each frame decoded whole and searched whole (no tracking)."""
    import itertools

    from aruco_abs_orient.detection import DetectorParams, MarkerDetector, decode_jpeg
    from aruco_abs_orient.markers import MarkerMap
    from aruco_abs_orient.offline.bagio import iter_images

    detector = MarkerDetector(MarkerMap.load(os.path.join(scen, "markers.yaml")).dictionary, DetectorParams())
    payloads = [p for _, p in itertools.islice(iter_images(os.path.join(scen, "scenario.bag")), frames)]
    c0, t0 = time.process_time(), time.perf_counter()
    for p in payloads:
        detector.detect(decode_jpeg(p))
    return {"frames": len(payloads), "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}


@contextlib.contextmanager
def _one_opencv_thread():
    """OpenCV on one thread inside (a generator worker's setting, a decoder thread's), as it was after."""
    import cv2

    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(threads)


def render_cost(frames: int) -> tuple:
    """(CPU s per frame of the ``demo`` preset, rendered and JPEG-encoded as a generator worker does it
    (one OpenCV thread), the demo's frame count)."""
    from aruco_abs_orient.synthetic.render import encode_jpeg
    from aruco_abs_orient.synthetic.scenario import PRESETS, Scenario
    from aruco_abs_orient.synthetic.world import render_frame

    with _one_opencv_thread():
        sc = Scenario(PRESETS["demo"])
        step = sc.frame_times.size // frames
        render_frame(sc, 0)  # caches
        t0 = time.process_time()
        for i in range(0, step * frames, step):
            encode_jpeg(render_frame(sc, i), sc.config.jpeg_quality)
        return (time.process_time() - t0) / frames, int(sc.frame_times.size)


def decoding(scen: str, base: str, cal: tuple, ours: dict, fps: float) -> None:
    """The shipped run ``ours`` (only the rows tracking reads decoded) against whole frames decoded, run now."""
    with open(base + "_whole_frames.yaml", "w") as f:
        f.write("tracking:\n  decode_rows: false\n")
    whole = run(scen, base + "_whole", extra=("--params", base + "_whole_frames.yaml", *cal))
    with open(os.path.join(base + "_ours", "summary.json")) as f:
        rows = json.load(f)["decoding"]
    same = filecmp.cmp(os.path.join(base + "_whole", "trajectory.tum"), os.path.join(base + "_ours", "trajectory.tum"),
                       shallow=False)
    print(f"decode: whole frames (decode_rows false) {whole['frames'] / whole['wall_s']:.1f} frames/s, "
          f"{whole['frames'] / whole['wall_s'] / fps:.2f}x real time, {1e3 * whole['cpu_s'] / whole['frames']:.1f} ms "
          f"CPU/frame, heading RMSE {heading_rmse(scen, base + '_whole'):.4f} deg; shipped / whole frames "
          f"{(ours['frames'] / ours['wall_s']) / (whole['frames'] / whole['wall_s']):.2f}x frames/s, "
          f"{whole['cpu_s'] / ours['cpu_s']:.2f}x less CPU; the same trajectory byte for byte: {same}; the shipped "
          f"run decoded {100 * rows['share']:.0f} % of the rows ({rows['in_part']} of {rows['frames']} frames in "
          f"part, {rows['completed']} of them decoded whole then for a search; {rows['decoder']})")


def speed(a) -> None:
    scen = a.speed_scenario or scenario(a.speed_seconds, "demo")
    cores = str(os.cpu_count() or 2)
    base = os.path.join(ROOT, ".cache", "bench", "offline_speed")
    cal = ("--calibration", calibration(scen))
    ours = run(scen, base + "_ours", extra=cal)  # the package's own default (aruco_abs_orient.offline)
    os.makedirs(os.path.dirname(base), exist_ok=True)
    with open(base + "_no_backoff.yaml", "w") as f:
        f.write("tracking:\n  lost_backoff_max_frames: 0\n")
    before = run(scen, base + "_before", env={"OPENBLAS_NUM_THREADS": cores},
                 extra=("--params", base + "_no_backoff.yaml", *cal))
    nv = naive(scen, a.naive_frames)
    fps = ours["frames"] / ours["bag_s"] if ours["bag_s"] > 0 else 30.0  # the bag's frame rate
    print(f"\nspeed: process on {scen} ({ours['frames']} frames, {ours['bag_s']:.1f} s at {fps:.0f} fps); "
          f"load average {os.getloadavg()[0]:.1f} on {cores} cores")
    print(f"{'way':<66} {'frames/s':>9} {'x real time':>12} {'CPU ms/frame':>13} {'heading RMSE':>13} "
          f"{'x real time, free cores':>24}")
    rmse = [f"{heading_rmse(scen, base + k):.4f} deg" for k in ("_ours", "_before")] + ["-"]
    free = [f"{r['bag_s'] / r['free_s']:.2f}" for r in (ours, before)] + ["-"]
    rows = [("process (one OpenBLAS thread, recovery searches back off)", ours["frames"], ours["wall_s"],
             ours["cpu_s"]),
            (f"before: OpenBLAS's {cores} threads, recovery searches without back-off", before["frames"],
             before["wall_s"], before["cpu_s"]),
            (f"naive: decode + full-frame search of every frame ({nv['frames']} frames)", nv["frames"],
             nv["wall_s"], nv["cpu_s"])]
    for (name, n, wall, cpu), err, f in zip(rows, rmse, free):
        print(f"{name:<66} {n / wall:>9.1f} {n / wall / fps:>12.2f} {1e3 * cpu / n:>13.1f} {err:>13} {f:>24}")
    r_ours, r_before, r_naive = (n / wall for _, n, wall, _ in rows)
    print(f"ratios: shipped / before {r_ours / r_before:.2f}x frames/s, {before['cpu_s'] / ours['cpu_s']:.2f}x less "
          f"CPU; shipped / naive {r_ours / r_naive:.2f}x frames/s; "
          f"stages of the shipped run, ms/frame: " + ", ".join(f"{k} {v:.1f}" for k, v in ours["ms"].items()))
    decoding(scen, base, cal, ours, fps)
    per, n_demo = render_cost(a.render_frames)
    print(f"render: demo preset, {a.render_frames} frames rendered + JPEG-encoded as a generator worker does: "
          f"{per:.3f} s/frame CPU; the 60 s demo ({n_demo} frames) on 2 workers: {n_demo * per / 2:.0f} s "
          "(budget 180 s)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--durations", type=float, nargs="+", default=[30.0, 120.0], help="bag lengths, s")
    ap.add_argument("--speed", action="store_true", help="only the speed section")
    ap.add_argument("--speed-seconds", type=float, default=20.0, help="length of the speed section's bag, s")
    ap.add_argument("--speed-scenario", help="a scenario directory for the speed section instead (read only)")
    ap.add_argument("--naive-frames", type=int, default=20, help="frames of the naive way (full search each)")
    ap.add_argument("--render-frames", type=int, default=10, help="demo frames timed for the render figure")
    a = ap.parse_args()
    if a.speed:
        speed(a)
        return 0
    rows = []
    for d in sorted(a.durations):
        scen = scenario(d)
        for video in (False, True):
            out = os.path.join(ROOT, ".cache", "bench", f"offline_{d:g}s_{'video' if video else 'bag'}_out")
            rows.append((d, "video" if video else "bag", run(scen, out, video)))
    print("\noffline processing, 3840x1920 at 30 fps: JPEG bag / mp4v video (this machine, 2 cores)")
    print(f"{'length':>6} {'input':>6} {'frames':>7} {'wall s':>8} {'x real time':>12} {'peak RSS MB':>12}  "
          "ms/frame (decode/track/solve)")
    for d, kind, r in rows:
        ms = "/".join(f"{r['ms'].get(k, 0.0):.1f}" for k in ("decode", "track", "solve"))
        print(f"{d:>5g}s {kind:>6} {r['frames']:>7} {r['wall_s']:>8.1f} {r['rtf']:>12.2f} {r['peak_rss_mb']:>12.0f}  "
              f"{ms}")
    for kind in ("bag", "video"):
        peaks = [r["peak_rss_mb"] for _, k, r in rows if k == kind]
        if len(peaks) >= 2:
            print(f"peak memory ratio, {kind}, {max(a.durations):g} s / {min(a.durations):g} s: "
                  f"{peaks[-1] / peaks[0]:.2f} (flat = 1)")
    speed(a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
