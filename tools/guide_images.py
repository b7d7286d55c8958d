"""The field guide's pictures of a good run and of typical bad ones (doc/field_guide.md, "Check the result").

In: two rendered scenarios of the ``ci`` preset (1920 px, 20 s), rendered into .cache/guide/ when missing: the
good one with the camera mounted as its lever arms say (``boresight_deg`` 0), the tilted one with the preset's
0.3° mounting error. Out: the user's workflow on them (:func:`good_and_bad_runs`: timesync --markers --plot,
calibrate --plot, process, evaluate --overview, through the CLI's own entry point) in four runs — good, the time
offset 50 ms off, one marker moved 5 cm in the map, the tilted camera processed without calibration — and the
ten plots of the guide copied into ``--out`` (default doc/images/), each reduced to a 256-colour PNG. Their titles
are printed: they are what the guide says to look for. About 3 minutes on 2 idle cores (the two renderings).

    python tools/guide_images.py [--out doc/images]
"""
import argparse
import json
import os
import shutil
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "src"))

MOVE_M = 0.05          # the moved marker: 5 cm along map x
OFFSET_ERROR_S = 0.05  # the wrong time offset: 50 ms
#: guide picture → (run, plot file)
PICTURES = {
    "check_timesync_good.png": ("good", "timesync.png"),
    "check_timesync_offset.png": ("offset", "timesync.png"),
    "check_markers_good.png": ("good", "marker_yaws.png"),
    "check_markers_moved.png": ("moved", "marker_yaws.png"),
    "check_heading_good.png": ("good", "heading_error.png"),
    "check_heading_offset.png": ("offset", "heading_error.png"),
    "check_calibration_good.png": ("good", "calibration.png"),
    "check_calibration_tilted.png": ("tilted", "calibration.png"),
    "check_overview_good.png": ("good", "overview.png"),
    "check_overview_moved.png": ("moved", "overview.png"),
}


def _cli(*args) -> str:
    """The ``aruco-abs-orient`` command in this process; its standard output (it must succeed)."""
    import contextlib
    import io

    from aruco_abs_orient.offline.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main([str(a) for a in args])
    if code:
        raise RuntimeError(f"aruco-abs-orient {' '.join(map(str, args))}: exit status {code}\n{out.getvalue()}")
    return out.getvalue()


def _offset(text: str) -> float:
    import re

    return float(re.findall(r"--time-offset ([-0-9.]+)", text)[-1])


def moved_map(markers: str, observations: str, out: str) -> int:
    """``markers`` with the marker seen most often in ``observations`` (a process run's CSV) moved ``MOVE_M`` m
    along map x, written to ``out``; returns its id."""
    import csv
    from collections import Counter

    import yaml

    with open(observations, newline="") as f:
        seen = Counter(int(row["id"]) for row in csv.DictReader(f))
    moved = seen.most_common(1)[0][0]
    with open(markers) as f:
        data = yaml.safe_load(f)
    for m in data["markers"]:
        if m["id"] == moved:
            m["position"][0] += MOVE_M
    with open(out, "w") as f:
        yaml.safe_dump(data, f)
    return moved


def good_and_bad_runs(good: str, out: str, tilted: str = None) -> dict:
    """The workflow on the scenario directory ``good`` (scenario.bag, markers.yaml, truth.tum) in four runs under
    ``out``: "good" (timesync --markers --plot, calibrate --refine-time-offset --plot with the odometry known to be
    levelled, as the generator's is by default, process with both,
    evaluate --overview), "offset" (processed with the offset 50 ms off), "moved" (with one marker moved 5 cm in
    the map given to process), "tilted" (the scenario ``tilted``, or ``good`` itself, processed without the
    calibration; its calibrate --plot is the tilted camera's picture). Returns {run: directory} and, under
    "moved_id", the moved marker's id."""
    os.makedirs(out, exist_ok=True)
    runs = {name: os.path.join(out, name) for name in ("good", "offset", "moved", "tilted")}
    bag, markers, truth = (os.path.join(good, n) for n in ("scenario.bag", "markers.yaml", "truth.tum"))
    levelled = os.path.join(out, "levelled.yaml")    # the scenarios' odometry is levelled, as with an IMU
    with open(levelled, "w") as f:
        f.write("calibration:\n  odom_levelled: true\n")
    offset = _offset(_cli("timesync", bag, "--markers", markers, "--plot", runs["good"], "--quiet"))
    cal = os.path.join(runs["good"], "calibration.yaml")
    offset = _offset(_cli("calibrate", bag, "--markers", markers, "--time-offset", offset, "--refine-time-offset",
                          "--every", 3, "--out", cal, "--plot", runs["good"], "--params", levelled, "--quiet"))
    _cli("process", bag, "--markers", markers, "--out", runs["good"], "--time-offset", offset, "--calibration", cal,
         "--quiet")
    moved = os.path.join(out, "markers_moved.yaml")
    moved_id = moved_map(markers, os.path.join(runs["good"], "observations.csv"), moved)
    _cli("process", bag, "--markers", markers, "--out", runs["offset"], "--time-offset", offset + OFFSET_ERROR_S,
         "--calibration", cal, "--quiet")
    _cli("process", bag, "--markers", moved, "--out", runs["moved"], "--time-offset", offset, "--calibration", cal,
         "--quiet")
    for name in ("offset", "moved"):   # the same recording's timesync --plot, beside each run as a user has it
        shutil.copy(os.path.join(runs["good"], "timesync.json"), runs[name])
    t_bag, t_markers, t_truth = bag, markers, truth
    if tilted is None:   # the good scenario's camera is the tilted one: its calibration picture shows it
        os.makedirs(runs["tilted"], exist_ok=True)
        for name in ("calibration.png", "timesync.json"):
            shutil.copy(os.path.join(runs["good"], name), runs["tilted"])
        t_offset = offset
    else:
        t_bag, t_markers, t_truth = (os.path.join(tilted, n) for n in ("scenario.bag", "markers.yaml", "truth.tum"))
        t_offset = _offset(_cli("timesync", t_bag, "--markers", t_markers, "--plot", runs["tilted"], "--quiet"))
        t_offset = _offset(_cli("calibrate", t_bag, "--markers", t_markers, "--time-offset", t_offset,
                                "--refine-time-offset", "--every", 3, "--out",
                                os.path.join(out, "tilted_calibration.yaml"), "--plot", runs["tilted"], "--params",
                                levelled, "--quiet"))
    _cli("process", t_bag, "--markers", t_markers, "--out", runs["tilted"], "--time-offset", t_offset, "--quiet")
    for name, run in runs.items():
        overview = [t_bag if name == "tilted" else bag, moved if name == "moved" else
                    t_markers if name == "tilted" else markers]
        _cli("evaluate", run, "--reference", t_truth if name == "tilted" else truth, "--overview", *overview)
    return {**runs, "moved_id": moved_id}


def main(argv=None) -> int:
    from PIL import Image, PngImagePlugin

    from aruco_abs_orient.plots import png_title
    from aruco_abs_orient.synthetic.bag import generate
    from aruco_abs_orient.synthetic.scenario import PRESETS

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=os.path.join(ROOT, "doc", "images"), help="where the pictures go")
    p.add_argument("--work", default=os.path.join(ROOT, ".cache", "guide"), help="scenarios and runs")
    a = p.parse_args(argv)
    from dataclasses import replace

    scenarios = {}
    for name, config in (("good", replace(PRESETS["ci"], boresight_deg=0.0)), ("tilted", PRESETS["ci"])):
        scenarios[name] = os.path.join(a.work, f"scenario_{name}")
        if not os.path.exists(os.path.join(scenarios[name], "scenario.bag")):
            print(f"rendering {scenarios[name]}", flush=True)
            generate(config, scenarios[name], progress=False, force=True)
    runs = good_and_bad_runs(scenarios["good"], os.path.join(a.work, "runs"), scenarios["tilted"])
    os.makedirs(a.out, exist_ok=True)
    titles = {}
    for picture, (run, plot) in PICTURES.items():
        source = os.path.join(runs[run], plot)
        titles[picture] = png_title(source)
        target = os.path.join(a.out, picture)
        info = PngImagePlugin.PngInfo()
        info.add_itxt("Title", titles[picture])                  # the answer stays in the picture
        Image.open(source).convert("RGB").quantize(256).save(target, optimize=True, pnginfo=info)
        print(f"{target} ({os.path.getsize(target) // 1024} kB): {titles[picture]}")
    with open(os.path.join(a.work, "titles.json"), "w") as f:
        json.dump(titles, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
