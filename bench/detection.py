#!/usr/bin/env python3
"""Issue 4 figures on rendered 360° frames ('realistic' profile: blur, noise, JPEG 85,
textured background), full size (3840×1920 by default). Prints one table per section:

  jpeg      decode options (ms/frame) and whether detection keeps its accuracy on each
  accuracy  centre bearing error by range and elevation (degrees)
  bias      signed elevation error at 1 m and 45–60°: sphere centre vs pixel-space centre
  pattern_bias  each id's mean centre error (its pattern's bias) against the cell widths, facing and turned
                away, beside calibrate's model, and with the pattern fit (what `map` detects with) in the same run
  range     detection rate 1–18 m of a 0.19 m DICT_4X4_50 marker facing the camera
            (this package vs plain OpenCV on the full frame)
  seam_pole markers straddling the ±180° seam and at ±70° elevation, 1.5 m
  fp        false detections over textured frames without markers
  speed     a moving-camera sequence: ms/frame of plain full-frame OpenCV detection vs the
            map-guided tracker, their ratio, and what each finds
  fullframe the whole-frame search (MarkerDetector.detect: seam, poles, rescue) vs one plain
            cv2.aruco call on the same frame (near, far, seam, pole, and three halls of the realistic
            world): ms, ratio, ids found
  opencv_api OpenCV 4.2's function API (.venv-noetic, a Noetic robot's Python stack) vs this venv's
            ArucoDetector on the same frames: markers found, bearing differences, ms/frame

Usage: bench/detection.py [--frames 60] [--width 3840] [--fp-frames 500] [--only speed,range]
"""
import argparse
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "src"))

from aruco_abs_orient.camera import Equirect, angle_between, azel_to_bearing, bearing_to_azel
from aruco_abs_orient.detection import DetectorParams, MarkerDetector, decode_jpeg, pixel_centre_bearing
from aruco_abs_orient.markers import Marker, MarkerMap
from aruco_abs_orient.synthetic.render import encode_jpeg, facing_marker, render_equirect
from aruco_abs_orient.tracking import MarkerTracker
from aruco_abs_orient.transforms import invert_T, make_T, rot_z, transform_points

DEG = math.pi / 180.0
SIZE = 0.19


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def table(title, header, rows):
    print(f"\n## {title}")
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) for i, h in enumerate(header)]
    print("  ".join(str(h).rjust(w) for h, w in zip(header, widths)))
    for r in rows:
        print("  ".join(str(c).rjust(w) for c, w in zip(r, widths)))


def timed(fn, repeat=5):
    fn()
    t = time.perf_counter()
    for _ in range(repeat):
        out = fn()
    return (time.perf_counter() - t) / repeat * 1000.0, out


def section_jpeg(args, det):
    import cv2

    rng = np.random.default_rng(1)
    ms = [facing_marker(i, SIZE, d * azel_to_bearing(-3.0 + 0.7 * i, rng.uniform(-0.2, 0.2)))
          for i, d in enumerate([1.5, 3.0, 5.0, 8.0, 10.0, 12.0])]
    grey = render_equirect(args.width, ms, seed=1, profile="clean")
    data = encode_jpeg(grey, 85)
    options = [
        ("cv2.imdecode GRAYSCALE", lambda: cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)),
        ("cv2.imdecode REDUCED_GRAYSCALE_2",
         lambda: cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_REDUCED_GRAYSCALE_2)),
    ]
    try:
        import simplejpeg

        options += [
            ("simplejpeg GRAY", lambda: simplejpeg.decode_jpeg(data, colorspace="GRAY")),
            ("simplejpeg GRAY fastdct", lambda: simplejpeg.decode_jpeg(data, colorspace="GRAY", fastdct=True)),
        ]
    except ImportError:
        pass
    options.append(("detection.decode_jpeg (used)", lambda: decode_jpeg(data)))
    rows = []
    for name, fn in options:
        ms_, img = timed(fn, args.repeat)
        img = img[:, :, 0] if img.ndim == 3 else img
        if img.shape[1] != args.width:  # reduced: detect at that size
            found = det.detect(img)
        else:
            found = det.detect(img)
        errs = [float(angle_between(o.centre, unit(ms[o.id].center))) / DEG for o in found if o.id < len(ms)]
        rows.append((name, f"{img.shape[1]}x{img.shape[0]}", f"{ms_:.1f}", f"{len(errs)}/{len(ms)}",
                     f"{np.median(errs):.4f}" if errs else "-"))
    table(f"JPEG decode of a {args.width}x{args.width // 2} Q85 frame ({len(data) // 1024} KiB), "
          "markers at 1.5-12 m", ["decoder", "size", "ms", "found", "median err deg"], rows)
    # what decoding only the tracked regions could save: the 1/8-scale decode entropy-decodes every block and
    # skips the full IDCT; a region decoder skips the IDCT outside the regions and the rows below the lowest
    # one, never the entropy decoding of the blocks above a region (these JPEGs have no restart markers)
    full_ms = timed(lambda: decode_jpeg(data), args.repeat)[0]
    floor_ms = timed(lambda: decode_jpeg(data, reduce=8), args.repeat)[0]
    print(f"entropy decoding of every block (1/8 scale, no full IDCT): {floor_ms:.1f} ms of the full decode's "
          f"{full_ms:.1f} ms ({100.0 * floor_ms / full_ms:.0f} %)")


def section_accuracy(args, det):
    dists = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]
    bands = [(0, 15), (15, 30), (30, 45), (45, 60)]
    res = {(d, b): [] for d in dists for b in bands}
    seen = {(d, b): 0 for d in dists for b in bands}
    for f in range(args.accuracy_frames):
        rng = np.random.default_rng(200 + f)
        for bi, (lo, hi) in enumerate(bands):
            ms = []
            for i, d in enumerate(dists):
                el = rng.uniform(lo, hi) * (1 if rng.random() < 0.5 else -1)
                ms.append(facing_marker(i, SIZE, d * azel_to_bearing(-3.0 + 0.55 * i + rng.uniform(0, 0.2), el * DEG),
                                        roll=rng.uniform(-0.6, 0.6)))
            found = {o.id: o for o in det.detect(render_equirect(args.width, ms, seed=300 + 7 * f + bi))}
            for i, d in enumerate(dists):
                seen[(d, bands[bi])] += 1
                if i in found:
                    res[(d, bands[bi])].append(float(angle_between(found[i].centre, unit(ms[i].center))) / DEG)
    rows = []
    for d in dists:
        row = [f"{d} m"]
        for b in bands:
            e = res[(d, b)]
            row.append(f"{np.median(e):.4f} ({len(e)}/{seen[(d, b)]})" if e else f"- (0/{seen[(d, b)]})")
        allv = sum((res[(d, b)] for b in bands), [])
        row.append(f"{np.median(allv):.4f}" if allv else "-")
        rows.append(row)
    allv = sum(res.values(), [])
    table(f"Centre bearing error, median degrees (found/rendered), {args.width} px; overall median "
          f"{np.median(allv):.4f} deg, p90 {np.percentile(allv, 90):.4f} deg",
          ["range"] + [f"|el| {lo}-{hi} deg" for lo, hi in bands] + ["all"], rows)


def section_bias(args, det):
    eq = Equirect(args.width, args.width // 2)
    rows = []
    for lo, hi in [(0, 15), (30, 45), (45, 60)]:
        ours, naive, naive_raw = [], [], []
        for f in range(args.bias_frames):
            rng = np.random.default_rng(400 + f + lo)
            ms = [facing_marker(i, SIZE, 1.0 * azel_to_bearing(-3.0 + 0.75 * i, rng.uniform(lo, hi) * DEG),
                                roll=rng.uniform(-0.6, 0.6)) for i in range(8)]
            img = render_equirect(args.width, ms, seed=500 + f + lo)
            for o in det.detect(img):
                el_true = float(bearing_to_azel(unit(ms[o.id].center))[1])
                ours.append((o.elevation - el_true) / DEG)
                naive.append((float(bearing_to_azel(pixel_centre_bearing(eq, o.corners_px))[1]) - el_true) / DEG)
            # what a plain pipeline does: OpenCV's corners, intersected in pixel space
            ids, corners, _ = det.backend.detect(img, det.params.min_marker_perimeter_px)
            for i, c in zip(ids, corners):
                if i < len(ms):
                    el_true = float(bearing_to_azel(unit(ms[i].center))[1])
                    naive_raw.append((float(bearing_to_azel(pixel_centre_bearing(eq, c))[1]) - el_true) / DEG)
        rows.append((f"{lo}-{hi}", len(ours), f"{np.mean(ours):+.4f}", f"{np.mean(naive):+.4f}",
                     f"{np.mean(naive_raw):+.4f}" if naive_raw else "-"))
    table("Signed elevation error at 1 m, mean degrees (roll ±35 deg)",
          ["|el| deg", "n", "sphere centre (ours)", "pixel-space centre, same corners",
           "pixel-space centre, OpenCV corners"], rows)


def section_pattern_bias(args, det):
    """Each id's mean centre error over renders at one range (sub-pixel positions and noise varied): the bias its
    pattern sets, the same on every frame; its rms over the ids along the azimuth and the elevation against the
    cell widths in pixels, for markers facing the camera and turned 50° about their vertical (seen from the side:
    narrower across), beside calibrate's model (calibration.bias, CalibrationParams.pattern_bias_*); and the same
    markers with the pattern fit (DetectorParams.pattern_fit, what ``map`` detects with) in the same run: its rms
    bias and the ratio of the edge fit's to it."""
    from dataclasses import replace

    from aruco_abs_orient.calibration import CalibrationParams
    from aruco_abs_orient.calibration.bias import marker_cell_widths, pattern_bias_sigma
    from aruco_abs_orient.synthetic.render import PlacedMarker
    from aruco_abs_orient.transforms import rot_y

    fitting = MarkerDetector("DICT_4X4_50", replace(det.params, pattern_fit=True))
    size, pitch, rows = 0.30, 2 * math.pi / args.width, []
    for turn in (0.0, 50.0):
        for cell_px in (1.6, 1.9, 2.2, 2.6, 3.1, 3.8):
            d = size / 6 / (cell_px * pitch)
            means, fitted, spread, widths = [], [], [], []
            for i in range(12):
                errs, errs_fit = [], []
                for k in range(args.bias_frames * 2):
                    rng = np.random.default_rng([i, k, int(100 * cell_px), int(turn)])
                    el = rng.uniform(5, 20) * DEG
                    m = facing_marker(i, size, d * azel_to_bearing(-2.0 + rng.uniform(-0.3, 0.3), el),
                                      roll=rng.uniform(-0.05, 0.05))
                    m = PlacedMarker(i, size, m.center, m.camera_R_marker @ rot_y((-1) ** i * turn * DEG))
                    img = render_equirect(args.width, [m], seed=int(rng.integers(10 ** 6)))
                    a0, e0 = bearing_to_azel(unit(m.center))
                    for detector, out in ((det, errs), (fitting, errs_fit)):
                        found = [o for o in detector.detect(img) if o.id == i]
                        if found:
                            a1, e1 = bearing_to_azel(found[0].centre)
                            out.append(((a1 - a0) * math.cos(e0), e1 - e0))
                            if detector is det:
                                widths.append(marker_cell_widths(found[0].centre[None], found[0].corners[None], 6)[0]
                                              / pitch)
                if len(errs) >= 3 and len(errs_fit) >= 3:
                    means.append(np.mean(errs, axis=0) / pitch)
                    fitted.append(np.mean(errs_fit, axis=0) / pitch)
                    spread.append(np.std(errs, axis=0) / pitch / math.sqrt(len(errs)))
            if not means:
                rows.append((f"{turn:.0f}", f"{cell_px:.1f}", f"{d:.1f}", 0, "-", "-", "-", "-", "-", "-"))
                continue
            rms = np.sqrt(np.mean(np.square(means), axis=0))
            rms_fit = np.sqrt(np.mean(np.square(fitted), axis=0))
            noise = np.sqrt(np.mean(np.square(spread), axis=0))
            width = np.mean(widths, axis=0)
            model = pattern_bias_sigma(CalibrationParams(), 1.0, width[None])[0]
            rows.append((f"{turn:.0f}", f"{cell_px:.1f}", f"{d:.1f}", len(means), f"{width[0]:.2f} × {width[1]:.2f}",
                         f"{rms[0]:.3f}, {rms[1]:.3f}", f"{noise[0]:.3f}, {noise[1]:.3f}",
                         f"{model[0]:.3f}, {model[1]:.3f}", f"{rms_fit[0]:.3f}, {rms_fit[1]:.3f}",
                         f"{np.max(rms) / max(np.max(rms_fit), 1e-9):.1f}×"))
    table(f"Pattern bias: rms over 12 ids of each id's mean centre error, px ({size} m markers, {args.width} px, "
          f"{args.bias_frames * 2} renders per id)",
          ["turned °", "cell px", "range m", "ids", "cells (az × el) px", "rms bias (az, el)",
           "noise of a mean (az, el)", "calibrate's model (az, el)", "pattern fit: rms bias (az, el)",
           "edge / fit"], rows)


def section_range(args, det):
    dists = list(range(1, 19))
    hits = np.zeros(len(dists))
    naive = np.zeros(len(dists))
    errs = [[] for _ in dists]
    ratios = [[] for _ in dists]
    for f in range(args.range_frames):
        rng = np.random.default_rng(600 + f)
        ms = [facing_marker(i, SIZE, d * azel_to_bearing(-3.05 + 6.1 * i / len(dists) + rng.uniform(0, 0.1),
                                                         rng.uniform(-0.3, 0.3)), roll=rng.uniform(-0.7, 0.7))
              for i, d in enumerate(dists)]
        img = render_equirect(args.width, ms, seed=700 + f)
        for o in det.detect(img):
            if o.id < len(dists) and float(angle_between(o.centre, unit(ms[o.id].center))) < 0.5 * DEG:
                hits[o.id] += 1
                errs[o.id].append(float(angle_between(o.centre, unit(ms[o.id].center))) / DEG)
                ratios[o.id].append(errs[o.id][-1] * DEG / o.sigma)
        ids, _, _ = det.backend.detect(img, det.params.min_marker_perimeter_px)
        for i in set(ids):
            if i < len(dists):
                naive[i] += 1
    eq = Equirect(args.width, args.width // 2)
    rows = [(f"{d} m", f"{2 * math.atan(SIZE / 2 / d) / eq.rad_per_px:.1f}",
             f"{100 * hits[i] / args.range_frames:.0f} %", f"{100 * naive[i] / args.range_frames:.0f} %",
             f"{np.median(errs[i]):.4f}" if errs[i] else "-", f"{np.median(ratios[i]):.2f}" if ratios[i] else "-")
            for i, d in enumerate(dists)]
    table(f"Detection rate of a {SIZE} m DICT_4X4_50 marker facing the camera, {args.width} px, "
          f"{args.range_frames} frames per range",
          ["range", "side px", "ours", "plain OpenCV", "median err deg", "median err/sigma (1.18 ideal)"], rows)


def section_seam_pole(args, det):
    seam_hit = seam_n = pole_hit = pole_n = 0
    seam_err, pole_err = [], []
    for f in range(args.range_frames):
        rng = np.random.default_rng(900 + f)
        # one marker per elevation band, so that none hides another
        seam = [facing_marker(i, SIZE, d * azel_to_bearing(math.pi + rng.uniform(-0.4, 0.4) * SIZE / d,
                                                           (el + rng.uniform(-2, 2)) * DEG),
                              roll=rng.uniform(-0.7, 0.7))
                for i, (d, el) in enumerate([(0.6, -38), (1.0, -12), (2.0, 8), (4.0, 22), (8.0, 36)])]
        pole = [facing_marker(10 + i, SIZE, 1.5 * azel_to_bearing(-3.0 + 1.0 * i + rng.uniform(0, 0.5),
                                                                   (70.0 if i % 2 else -70.0) * DEG),
                              roll=rng.uniform(-0.7, 0.7)) for i in range(6)]
        found = {o.id: o for o in det.detect(render_equirect(args.width, seam + pole, seed=950 + f))}
        for m, hits, errs in [(m, "seam", seam_err) for m in seam] + [(m, "pole", pole_err) for m in pole]:
            ok = m.id in found
            if hits == "seam":
                seam_n += 1
                seam_hit += ok
            else:
                pole_n += 1
                pole_hit += ok
            if ok:
                errs.append(float(angle_between(found[m.id].centre, unit(m.center))) / DEG)
    table(f"Markers on the ±180 deg seam (0.6-8 m, |el| < 40 deg) and at ±70 deg elevation, 1.5 m "
          f"({args.range_frames} frames)", ["case", "found", "rate", "median err deg", "max err deg"],
          [("seam", f"{seam_hit}/{seam_n}", f"{100.0 * seam_hit / seam_n:.0f} %", f"{np.median(seam_err):.4f}",
            f"{max(seam_err):.4f}"),
           ("±70 deg", f"{pole_hit}/{pole_n}", f"{100.0 * pole_hit / pole_n:.0f} %", f"{np.median(pole_err):.4f}",
            f"{max(pole_err):.4f}")])


def section_fp(args, det):
    ids_in_map = list(range(10))
    mmap = MarkerMap([Marker(i, np.array([float(i), 1.0, 1.0]), SIZE, 0.002) for i in ids_in_map])
    tracker = MarkerTracker(mmap, det.params)
    raw = ours = accepted = 0
    t = time.perf_counter()
    for f in range(args.fp_frames):
        img = render_equirect(args.width, [], seed=10000 + f)
        ids, _, _ = det.backend.detect(img, det.params.min_marker_perimeter_px)
        raw += len(ids)
        tracker.reset()
        res = tracker.process(img, None)  # no pose: the whole frame, MarkerDetector.detect
        ours += len(res.observations) + res.stats.rejected_unknown
        accepted += len(res.observations)
    table(f"False detections over {args.fp_frames} textured {args.width} px frames without markers "
          f"({time.perf_counter() - t:.0f} s)",
          ["plain OpenCV (any id)", "ours (any id)", "tracker accepted (map ids 0-9)"], [(raw, ours, accepted)])


def section_speed(args, det):
    positions = [(6.0, 1.0, 1.5), (2.5, -3.0, 1.2), (-4.0, 3.0, 2.0), (9.0, -5.0, 1.4), (-9.0, -2.0, 1.8),
                 (1.0, 6.5, 1.0), (-6.0, -6.0, 2.4), (11.0, 4.0, 1.5)]
    mmap = MarkerMap([Marker(i, np.array(p), SIZE, 0.002) for i, p in enumerate(positions)])
    tracker = MarkerTracker(mmap, det.params)
    rng = np.random.default_rng(7)
    naive_ms, full_ms, tracked_ms = [], [], []
    n_naive = n_both = n_tracked = n_full = 0
    extra = {}
    modes = {}
    for k in range(args.frames):
        # 30 fps, walking at 1 m/s, the heading swinging ±20 deg (up to 31 deg/s)
        t = k / 30.0
        yaw = 0.35 * math.sin(2 * math.pi * t / 4.0)
        t_cam = np.array([-3.0 + 1.0 * t, 0.3 * math.sin(t), 1.0])
        map_T_camera = make_T(rot_z(yaw), t_cam)
        pc = transform_points(invert_T(map_T_camera), mmap.positions())
        ms = [facing_marker(i, SIZE, pc[i]) for i in range(len(positions))]
        img = render_equirect(args.width, ms, seed=3, background_yaw=yaw, noise_seed=k)
        # the predicted pose: truth perturbed (0.2 deg yaw, 2 cm), as a running correction gives
        noisy = make_T(rot_z(yaw + rng.normal(0.0, 0.2 * DEG)), t_cam + rng.normal(0.0, 0.02, 3))
        t = time.perf_counter()
        ids, _, _ = det.backend.detect(img, det.params.min_marker_perimeter_px)
        naive_ms.append((time.perf_counter() - t) * 1000.0)
        t = time.perf_counter()
        full = det.detect(img)
        full_ms.append((time.perf_counter() - t) * 1000.0)
        res = tracker.process(img, noisy)
        modes[res.stats.mode] = modes.get(res.stats.mode, 0) + 1
        if res.stats.mode == "tracked":
            tracked_ms.append(res.stats.time_ms)
        naive_set = {i for i in ids if i in mmap}
        got = {o.id for o in res.observations}
        n_naive += len(naive_set)
        n_both += len(naive_set & got)
        n_tracked += len(got)
        n_full += len({o.id for o in full if o.id in mmap})
        for i in got - naive_set:
            d = float(np.linalg.norm(pc[i]))
            el = float(bearing_to_azel(pc[i])[1]) / DEG
            key = "far (>8 m)" if d > 8 else ("pole (|el|>55)" if abs(el) > 55 else "other")
            extra[key] = extra.get(key, 0) + 1
    naive_med = float(np.median(naive_ms))
    tracked_med = float(np.median(tracked_ms))
    rows = [
        ("plain OpenCV, full frame", f"{naive_med:.1f}", f"{np.percentile(naive_ms, 90):.1f}", "1.0", n_naive),
        ("ours, full frame (seam, poles, rescue)", f"{np.median(full_ms):.1f}", f"{np.percentile(full_ms, 90):.1f}",
         f"{naive_med / np.median(full_ms):.2f}", n_full),
        ("ours, tracked (ROI views + sweep tile)", f"{tracked_med:.1f}", f"{np.percentile(tracked_ms, 90):.1f}",
         f"{naive_med / tracked_med:.2f}", n_tracked),
    ]
    table(f"Speed on a {args.frames}-frame {args.width} px 30 fps sequence, {len(positions)} markers 1-15 m "
          f"(tracker modes {modes})",
          ["pipeline", "ms/frame median", "p90", "speed-up vs plain", "marker-frames found"], rows)
    print(f"tracked finds {n_both}/{n_naive} = {100.0 * n_both / max(n_naive, 1):.1f} % of what plain OpenCV "
          f"finds; plus {sum(extra.values())} it misses: {extra}")


def fullframe_scenes(width):
    """Frames of the fullframe section: (name, grey image, truth {id: unit bearing}): markers on a textured
    panorama (near, far, seam, pole, none), then frames of the realistic world's hall (three seeds: three halls,
    their walls, pillars and posters, 10 s into the demo drive, JPEG as in a bag; the truth is each marker the
    camera sees within 12 m and 80° of its face, where the stitched image shows its centre)."""
    import dataclasses

    from aruco_abs_orient.synthetic.render import PROFILES
    from aruco_abs_orient.synthetic.scenario import PRESETS, Scenario
    from aruco_abs_orient.synthetic.world import render_frame

    rng = np.random.default_rng(31)
    scenes = [
        ("near 1-3 m", [facing_marker(i, SIZE, d * azel_to_bearing(-3.0 + 0.75 * i, rng.uniform(-0.6, 0.6)),
                                      roll=rng.uniform(-0.7, 0.7))
                        for i, d in enumerate([1.0, 1.5, 2.0, 2.5, 3.0] * 2)]),
        ("mid 2-12 m", [facing_marker(i, SIZE, d * azel_to_bearing(-3.0 + 0.55 * i, rng.uniform(-0.3, 0.3)),
                                      roll=rng.uniform(-0.7, 0.7)) for i, d in enumerate(range(2, 13))]),
        ("far 10-12 m", [facing_marker(i, SIZE, d * azel_to_bearing(-3.0 + 0.6 * i, rng.uniform(-0.3, 0.3)),
                                       roll=rng.uniform(-0.7, 0.7)) for i, d in enumerate([10, 11, 12] * 3 + [12])]),
        ("seam 0.6-8 m", [facing_marker(i, SIZE, d * azel_to_bearing(math.pi + rng.uniform(-0.4, 0.4) * SIZE / d,
                                                                     el * DEG), roll=rng.uniform(-0.7, 0.7))
                          for i, (d, el) in enumerate([(0.6, -38), (1.0, -12), (2.0, 8), (4.0, 22), (8.0, 36)])]),
        ("pole ±60-75 deg", [facing_marker(i, SIZE, d * azel_to_bearing(-3.0 + 0.6 * i, (1 if i % 2 else -1)
                                                                        * rng.uniform(60, 75) * DEG),
                                           roll=rng.uniform(-0.7, 0.7))
                             for i, d in enumerate([1.0, 1.5, 2.0, 3.0] * 2)]),
        ("textured, no marker", []),
    ]
    out = [(name, render_equirect(width, ms, seed=40 + k), {m.id: unit(m.center) for m in ms})
           for k, (name, ms) in enumerate(scenes)]
    for seed in (301, 302, 303):
        sc = Scenario(dataclasses.replace(PRESETS["demo"], seed=seed, width=width))
        index = int(np.searchsorted(sc.frame_times, 10.0))
        _, ids, bearings = sc.marker_bearings(sc.frame_times[index])
        image = render_frame(sc, index, PROFILES[sc.config.profile])  # with its JPEG round trip, as in a bag
        out.append((f"hall, seed {seed}", image, dict(zip(ids.tolist(), bearings))))
    return out


def section_fullframe(args, det):
    import cv2

    rows, ratios, cpu_ratios = [], [], []
    for name, img, truth in fullframe_scenes(args.width):
        runs = {"plain": ([], []), "ours": ([], [])}  # wall ms, CPU ms (all threads)
        for _ in range(args.repeat):  # interleaved: both see the same machine load
            for key, fn in (("plain", lambda im=img: det.backend.detect(im, det.params.min_marker_perimeter_px)),
                            ("ours", lambda im=img: det.detect(im))):
                t, c = time.perf_counter(), time.process_time()
                out = fn()
                runs[key][0].append((time.perf_counter() - t) * 1000.0)
                runs[key][1].append((time.process_time() - c) * 1000.0)
                if key == "plain":
                    ids = out[0]
                else:
                    found = out
        (pw, pc), (ow, oc) = [[float(np.median(x)) for x in runs[k]] for k in ("plain", "ours")]
        ratios.append(ow / pw)
        cpu_ratios.append(oc / pc)
        right = [o for o in found if o.id in truth and float(angle_between(o.centre, truth[o.id])) < 0.5 * DEG]
        errs = [float(angle_between(o.centre, truth[o.id])) / DEG for o in right]
        rows.append((name, f"{pw:.1f}", f"{ow:.1f}", f"{ow / pw:.2f}", f"{pc:.1f}", f"{oc:.1f}", f"{oc / pc:.2f}",
                     f"{len({i for i in ids if i in truth})}/{len(truth)}", f"{len(right)}/{len(truth)}",
                     len(found) - len(right), f"{np.median(errs):.4f}" if errs else "-"))
    table(f"Whole-frame search (MarkerDetector.detect) vs plain cv2.aruco (one detectMarkers call, same dictionary "
          f"and OpenCV settings, whole grey frame), {args.width} px, medians of {args.repeat} interleaved runs, "
          f"{cv2.getNumThreads()} OpenCV threads, {os.getloadavg()[0]:.1f} load; median ratio wall "
          f"{np.median(ratios):.2f}, CPU {np.median(cpu_ratios):.2f}",
          ["frame", "plain ms", "ours ms", "ratio", "plain CPU ms", "ours CPU ms", "CPU ratio", "plain ids",
           "ours ids", "ours extra", "median err deg"], rows)


SECTIONS = {"jpeg": section_jpeg, "accuracy": section_accuracy, "bias": section_bias,
            "pattern_bias": section_pattern_bias, "range": section_range,
            "seam_pole": section_seam_pole, "fp": section_fp, "speed": section_speed,
            "fullframe": section_fullframe}
NOETIC_PY = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".venv-noetic", "bin", "python")
#: run by .venv-noetic's python: full-frame detection in .npy frames; bearings and ms per frame as JSON
NOETIC_DETECT = (
    "import json, sys, time, numpy as np\n"
    "from aruco_abs_orient.detection import MarkerDetector\n"
    "det, out = MarkerDetector('DICT_4X4_50'), []\n"
    "for f in sys.argv[1:]:\n"
    "    img = np.load(f)\n"
    "    t = time.perf_counter()\n"
    "    obs = det.detect(img)\n"
    "    out.append({'ms': (time.perf_counter() - t) * 1000.0, 'obs': {o.id: o.centre.tolist() for o in obs}})\n"
    "print(json.dumps({'api': det.backend.api, 'frames': out}))\n")


def section_opencv_api(args, det):
    """Issue 19: OpenCV 4.2's function API (Noetic's python3-opencv, in .venv-noetic) vs this venv's
    OpenCV on the same rendered frames, per kind of scene."""
    import json
    import subprocess
    import tempfile

    import cv2

    if not os.path.isfile(NOETIC_PY):
        print(f"\n## OpenCV 4.2 function API: skipped, no {NOETIC_PY} (make setup builds it from a Python 3.8)")
        return
    scenes = {"1-12 m, |el| < 20 deg": [], "seam, 0.6-8 m": [], "+-70 deg, 1.5 m": [], "0.5-3 m, 45-60 deg": []}
    for f in range(args.range_frames):
        rng = np.random.default_rng(1900 + f)
        scenes["1-12 m, |el| < 20 deg"].append(
            [facing_marker(i, SIZE, d * azel_to_bearing(-3.0 + 0.5 * i + rng.uniform(0, 0.2),
                                                        rng.uniform(-20, 20) * DEG), roll=rng.uniform(-0.7, 0.7))
             for i, d in enumerate(range(1, 13))])
        scenes["seam, 0.6-8 m"].append(
            [facing_marker(i, SIZE, d * azel_to_bearing(math.pi + rng.uniform(-0.4, 0.4) * SIZE / d, el * DEG),
                           roll=rng.uniform(-0.7, 0.7))
             for i, (d, el) in enumerate([(0.6, -38), (1.0, -12), (2.0, 8), (4.0, 22), (8.0, 36)])])
        scenes["+-70 deg, 1.5 m"].append(
            [facing_marker(i, SIZE, 1.5 * azel_to_bearing(-3.0 + 1.0 * i + rng.uniform(0, 0.5),
                                                          (70 if i % 2 else -70) * DEG), roll=rng.uniform(-0.7, 0.7))
             for i in range(6)])
        scenes["0.5-3 m, 45-60 deg"].append(
            [facing_marker(i, SIZE, d * azel_to_bearing(-2.5 + 1.2 * i, rng.uniform(45, 60) * DEG * (-1) ** i),
                           roll=rng.uniform(-0.7, 0.7)) for i, d in enumerate([0.5, 1.0, 1.5, 2.0, 3.0])])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for s, (name, frames) in enumerate(scenes.items()):
            imgs = [render_equirect(args.width, ms, seed=1950 + 31 * s + f) for f, ms in enumerate(frames)]
            files = [os.path.join(tmp, f"{s}_{f}.npy") for f in range(len(imgs))]
            for path, img in zip(files, imgs):
                np.save(path, img)
            env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
            out = subprocess.run([NOETIC_PY, "-c", NOETIC_DETECT] + files, stdout=subprocess.PIPE, text=True, env=env,
                                 check=True)
            old = json.loads(out.stdout.strip().splitlines()[-1])
            n = found_new = found_old = same = 0
            diffs, ms_new = [], []
            for img, ms, o in zip(imgs, frames, old["frames"]):
                t = time.perf_counter()
                new = {ob.id: ob.centre for ob in det.detect(img)}
                ms_new.append((time.perf_counter() - t) * 1000.0)
                o_ids = {int(i): np.array(c) for i, c in o["obs"].items()}
                n += len(ms)
                found_new += len(new)
                found_old += len(o_ids)
                same += sorted(new) == sorted(o_ids)
                diffs += [float(angle_between(new[i], o_ids[i])) / DEG for i in set(new) & set(o_ids)]
            rows.append((name, n, found_new, found_old, f"{same}/{len(imgs)}",
                         f"{np.median(diffs):.5f}" if diffs else "-", f"{max(diffs):.5f}" if diffs else "-",
                         f"{np.median(ms_new):.0f}", f"{np.median([o['ms'] for o in old['frames']]):.0f}"))
    table(f"OpenCV 4.2 function API ({old['api']}, .venv-noetic: Python 3.8, numpy 1.17) vs OpenCV "
          f"{cv2.__version__} {det.backend.api} on the same {args.width} px frames ({args.range_frames} per scene)",
          ["scene", "rendered", f"found {det.backend.api}", "found 4.2", "same ids", "median diff deg",
           "max diff deg", "ms/frame here", "ms/frame 4.2"], rows)


SECTIONS["opencv_api"] = section_opencv_api


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60, help="frames of the speed sequence")
    ap.add_argument("--width", type=int, default=3840, help="equirect width in pixels")
    ap.add_argument("--fp-frames", type=int, default=500, help="marker-free frames for the false-positive count")
    ap.add_argument("--range-frames", type=int, default=10, help="frames per range of the range curve")
    ap.add_argument("--accuracy-frames", type=int, default=3, help="frames per elevation band")
    ap.add_argument("--bias-frames", type=int, default=4, help="frames (8 markers each) per elevation band")
    ap.add_argument("--repeat", type=int, default=5, help="repetitions of each JPEG decode")
    ap.add_argument("--only", default=",".join(SECTIONS), help="comma-separated sections: " + ", ".join(SECTIONS))
    args = ap.parse_args(argv)
    wanted = [s.strip() for s in args.only.split(",") if s.strip()]
    unknown = [s for s in wanted if s not in SECTIONS]
    if unknown:
        ap.error(f"unknown section(s) {', '.join(unknown)}; choose from {', '.join(SECTIONS)}")
    det = MarkerDetector("DICT_4X4_50", DetectorParams())
    print(f"# bench/detection.py: {args.width}x{args.width // 2}, OpenCV ArUco API {det.backend.api}, "
          f"{os.cpu_count()} CPUs")
    for name in wanted:
        t = time.perf_counter()
        SECTIONS[name](args, det)
        print(f"({name}: {time.perf_counter() - t:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
