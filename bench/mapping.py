#!/usr/bin/env python3
"""The marker map from the recording itself (``aruco-abs-orient map``), against the truth.

Passes (``--passes``):

  rendered  per seed of the realistic world (preset demo: the hall, 3840 px, 30 fps, 60 s, 30 ms rolling shutter,
            10 markers of 19 cm at 2-12 m), every image searched for every marker (cached per seed), the network
            with the camera's calibration known (its true mounting, readout and lenses: a camera calibrated
            before) and no control marker: per marker mapped its error against hidden.yaml, its worst-axis σ and
            its normalised error √(eᵀC⁻¹e) (≤ 3 for an honest σ in 97 % of cases), the baseline it was seen
            from; then `process` of the drive with the mapped map and with the true map (hidden.yaml's
            positions) and `evaluate`: the heading RMSE of both and their ratio; the network's CPU time.
  control   the same drives with two control markers (the survey's first two, 2 mm σ): each control's
            difference from the free network in its σ (√χ², 3 degrees of freedom) and whether the network used
            it; the other markers' errors with the controls.
  compare   the first seed recorded again with its lowest id knocked by (0, 3, -4) cm (scenario moved_marker):
            `map --compare` of the two maps: the markers reported moved.
  bearings  the detections themselves, before any network: each sighting's bearing against the true marker centre
            seen from the true pose at its row's capture time (truth.tum, the true mounting, lenses and readout,
            the camera clock's offset and rate from hidden.yaml), through the lenses' marker rays; the spread
            per range and near the lenses' seams (within 6° of them) against the detection's own σ, and the
            RMS of each marker's mean error (what the network's bias_deg stands for). The truth is sampled per
            image and interpolated (slerp) to the rows; the sightings on the middle rows need no interpolation.
  information  what holds the map back: the rendered pass's network (same sightings) on the recording as it is
            and with one of the instruments' errors taken out of it, regenerated from the scenario (its own
            random draws, that error set to 0): the VO's yaw exact (no walk, no drift: δ(t) known but for a
            constant), the VO's positions without their jitter, the prism's noise divided by 4 or drawn again
            (five draws: how much the count owes to the recording's one draw); per case the
            markers with a 3 m baseline within 5 mm, |error|/σ ≤ 3, and each miss's error along its covariance's
            worst axis (a far marker's sight line) and across it.
  scale     the network's CPU time and peak memory (tracemalloc) for 50 markers and 10 minutes of the generator's
            exact bearings (synthetic.feed, 0.02° noise, every 3rd image and every image).

Scenarios are cached in .cache/bench/mapping/ (keyed by a digest of their configuration); the detections in
each scenario's directory (observations.pkl). Rendering one 60 s scenario takes about 2.5 min on 2 cores, detecting
its 1800 images about 3 min of CPU (4.5 min before the rescue's first look): 10 seeds about 70 min.

Usage: bench/mapping.py [--seeds 101 ... 110] [--passes rendered control compare bearings information scale]
                        [--workers 2]
"""
import argparse
import dataclasses
import math
import os
import pickle
import sys
import time
import tracemalloc

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "src"))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "test"))

from _workflow import cli, hidden_of, scenario_dir, true_calibration  # noqa: E402

from aruco_abs_orient.calibration import Recording  # noqa: E402
from aruco_abs_orient.calibration.io import load_calibration  # noqa: E402
from aruco_abs_orient.detection import DetectorParams  # noqa: E402
from aruco_abs_orient.mapping import MappingParams, MapUnknowns, map_markers  # noqa: E402
from aruco_abs_orient.mapping.compare import compare_maps  # noqa: E402
from aruco_abs_orient.mapping.output import mapped_map  # noqa: E402
from aruco_abs_orient.markers import Marker, MarkerMap  # noqa: E402
from aruco_abs_orient.offline.bagio import read_bag_data  # noqa: E402
from aruco_abs_orient.offline.calibrate import collect_observations  # noqa: E402
from aruco_abs_orient.synthetic.scenario import PRESETS, Scenario  # noqa: E402
from aruco_abs_orient.transforms import matrix_to_quat  # noqa: E402
from aruco_abs_orient.tum import Trajectory, read_tum  # noqa: E402

MOVE = (0.0, 0.03, -0.04)   # m, the knocked marker of the compare pass (5 cm)


def true_map(scen: str) -> str:
    """hidden.yaml's marker positions and normals as a markers YAML (the map a perfect survey gives)."""
    hidden, survey = hidden_of(scen), MarkerMap.load(os.path.join(scen, "markers.yaml"))
    path = os.path.join(scen, "true_markers.yaml")
    MarkerMap([Marker(m.id, np.array(hidden["marker_positions"][m.id]), m.size, 0.0005,
                      np.array(hidden["marker_normals"][m.id])) for m in survey], survey.dictionary).save(path)
    return path


def observations(scen: str):
    """Every sighting of every marker in every image of the scenario's bag, detected as ``map`` detects them
    (each small marker's pattern fitted: ``mapping.pattern_fit``), cached."""
    fit = MappingParams().pattern_fit
    cache = os.path.join(scen, "observations_fit.pkl" if fit else "observations.pkl")
    if os.path.exists(cache):
        with open(cache, "rb") as f:
            return pickle.load(f)
    bag = os.path.join(scen, "scenario.bag")
    data = read_bag_data(bag)
    t0 = time.process_time()
    obs = collect_observations(bag, None, data=data, progress=False, dictionary=hidden_of(scen)["config"]["dictionary"],
                               detector_params=DetectorParams(pattern_fit=fit))
    print(f"  detected {len(obs.ids)} sightings in {obs.frames} images: {time.process_time() - t0:.0f} s CPU",
          flush=True)
    with open(cache, "wb") as f:
        pickle.dump((obs, data), f)
    return obs, data


def network(scen: str, control: MarkerMap = None, data=None):
    """map_markers on the cached sightings with the true calibration (and the recording's odometry and prism
    track, or those of ``data``): (result, CPU s)."""
    obs, recorded = observations(scen)
    data = recorded if data is None else data
    hidden, cal = hidden_of(scen), load_calibration(true_calibration(scen))
    rec = Recording(obs.times, obs.ids, obs.bearings, obs.sigmas, data.odom,
                    data.prism_stamps + hidden["camera_time_offset"], data.prism_positions,
                    control if control is not None else MarkerMap([]), cal["camera"], cal["prism"], obs.rows,
                    cal["lenses"])
    t0 = time.process_time()
    res = map_markers(rec, obs.corners, hidden["config"]["marker_size"], MapUnknowns(), readout=float(cal["readout"]))
    return res, time.process_time() - t0


def errors(res, hidden: dict) -> list:
    """(id, |error| mm, worst-axis σ mm, √(eᵀC⁻¹e), baseline m) per mapped marker."""
    out = []
    for m in res.with_status("mapped"):
        e = m.position - np.array(hidden["marker_positions"][m.id])
        out.append((m.id, 1e3 * float(np.linalg.norm(e)), 1e3 * math.sqrt(float(np.linalg.eigvalsh(m.cov).max())),
                    math.sqrt(float(e @ np.linalg.solve(m.cov, e))), m.baseline))
    return out


def heading_rmse(scen: str, markers: str, run: str) -> float:
    cli("process", os.path.join(scen, "scenario.bag"), "--markers", markers, "--out", run, "--time-offset",
        hidden_of(scen)["camera_time_offset"], "--calibration", true_calibration(scen), "--quiet")
    cli("evaluate", run, "--reference", os.path.join(scen, "truth.tum"))
    with open(os.path.join(run, "report.json")) as f:
        import json

        return json.load(f)["heading_ape"]["rmse_deg"]


def pass_rendered(seeds) -> None:
    print("\n## rendered: realistic world (demo preset), 60 s, no control marker, the camera's calibration known")
    print(f"{'seed':>5} {'mapped':>7} {'refused':>8} {'left out':>9} {'≤5 mm (≥3 m base)':>18} {'z≤3':>6} "
          f"{'worst err mm':>13} {'worst z':>8} {'RMSE mapped':>12} {'RMSE true':>10} {'ratio':>6} {'CPU s':>6}")
    rows = []
    for seed in seeds:
        scen = scenario_dir(dataclasses.replace(PRESETS["demo"], seed=seed), "mapping", ARGS.workers)
        res, cpu = network(scen)
        hidden = hidden_of(scen)
        err = errors(res, hidden)
        mm = mapped_map(res, hidden["config"]["marker_size"], hidden["config"]["dictionary"])
        path = os.path.join(scen, "mapped_markers.yaml")
        mm.save(path)
        mapped = heading_rmse(scen, path, os.path.join(scen, "runs", "mapped"))
        truth = heading_rmse(scen, true_map(scen), os.path.join(scen, "runs", "true"))
        base = [e for e in err if e[4] >= 3.0]
        within = sum(e[1] <= 5.0 for e in base)
        honest = sum(e[3] <= 3.0 for e in err)
        rows.append((err, mapped, truth))
        print(f"{seed:>5} {len(err):>7} {len(res.with_status('refused')):>8} {len(res.with_status('left out')):>9} "
              f"{within:>12}/{len(base):<5} {honest:>3}/{len(err):<2} {max(e[1] for e in err):>13.2f} "
              f"{max(e[3] for e in err):>8.2f} {mapped:>12.4f} {truth:>10.4f} {mapped / truth:>6.2f} {cpu:>6.1f}",
              flush=True)
        for m in res.with_status("refused") + res.with_status("left out"):
            print(f"        marker {m.id} {m.status}: {m.reason[:150]}")
    base = [e for err, _, _ in rows for e in err if e[4] >= 3.0]
    every = [e for err, _, _ in rows for e in err]
    print(f"all: {sum(e[1] <= 5.0 for e in base)}/{len(base)} markers with ≥ 3 m baseline within 5 mm "
          f"({100 * np.mean([e[1] <= 5.0 for e in base]):.0f} %), {sum(e[3] <= 3.0 for e in every)}/{len(every)} "
          f"with |error|/σ ≤ 3; error median {np.median([e[1] for e in every]):.2f} mm, 95th percentile "
          f"{np.percentile([e[1] for e in every], 95):.2f} mm; heading RMSE ratio mapped/true: mean "
          f"{np.mean([m / t for _, m, t in rows]):.2f}, worst {max(m / t for _, m, t in rows):.2f}", flush=True)


def pass_control(seeds) -> None:
    print("\n## control: two control markers (the survey's first two, 2 mm σ)")
    print(f"{'seed':>5} {'control':>8} {'√χ² vs network':>15} {'used':>5} {'others ≤5 mm':>13} {'z≤3':>6}")
    for seed in seeds:
        scen = scenario_dir(dataclasses.replace(PRESETS["demo"], seed=seed), "mapping", ARGS.workers)
        survey = MarkerMap.load(os.path.join(scen, "markers.yaml"))
        control = MarkerMap([survey[i] for i in survey.ids[:2]], survey.dictionary)
        res, _ = network(scen, control)
        err = [e for e in errors(res, hidden_of(scen)) if e[0] not in control]
        for mid in control.ids:
            m = res.markers.get(mid)
            c = m.control if m is not None else None
            print(f"{seed:>5} {mid:>8} " + (f"{c[1]:>15.2f} {str(c[2]):>5}" if c else f"{'not placed':>15} {'-':>5}")
                  + f" {sum(e[1] <= 5.0 for e in err):>7}/{len(err):<5} {sum(e[3] <= 3.0 for e in err):>3}/{len(err)}",
                  flush=True)


def pass_compare(seeds) -> None:
    seed = seeds[0]
    before = scenario_dir(dataclasses.replace(PRESETS["demo"], seed=seed), "mapping", ARGS.workers)
    after = scenario_dir(dataclasses.replace(PRESETS["demo"], seed=seed, moved_marker=MOVE), "mapping", ARGS.workers)
    hidden = hidden_of(before)
    maps = []
    for scen in (before, after):
        res, _ = network(scen)
        maps.append(mapped_map(res, hidden["config"]["marker_size"], hidden["config"]["dictionary"]))
    comp = compare_maps(maps[1], maps[0])
    knocked = Scenario.from_hidden(os.path.join(before, "hidden.yaml")).markers.ids[0]
    print(f"\n## compare: seed {seed} recorded again with marker {knocked} knocked by {MOVE} m")
    for m in comp.moves:
        print(f"  marker {m.id}: {1e3 * m.distance:.1f} mm, {m.chi:.1f} σ (limit {comp.limit:.1f}) "
              f"{'MOVED' if m.moved else ''}")
    print("\n".join(comp.lines("the first recording")), flush=True)


#: the information pass's cases: the scenario's configuration changed so (None: the recording as it is)
INFORMATION = (("as recorded", None),
               ("VO yaw exact", {"vo_yaw_walk_deg_per_sqrt_s": 0.0, "vo_yaw_drift_deg_per_min": 0.0}),
               ("VO positions without jitter", {"vo_translation_noise": 0.0}),
               ("prism noise / 4", {"prism_noise": 0.25})) + tuple(
                   (f"prism noise drawn again ({k})", {"prism_draw": k}) for k in range(1, 6))


def without(scen: str, change: dict):
    """The recording's odometry and prism track with one error of the scenario changed (``INFORMATION``): the
    odometry regenerated at its stamps from the scenario with ``change`` (the generator's other draws stay), the
    prism's noise (its fixes against the noise-free track) scaled by ``change["prism_noise"]``, or drawn again
    (``change["prism_draw"]``: the draw's seed, with the scenario's)."""
    _, data = observations(scen)
    sc = Scenario.from_hidden(os.path.join(scen, "hidden.yaml"))
    c = sc.config
    exact = sc.prism_position(data.prism_stamps)     # the total station's clock is the true one
    if "prism_noise" in change:
        return dataclasses.replace(data, prism_positions=exact + change["prism_noise"] * (data.prism_positions
                                                                                          - exact))
    if "prism_draw" in change:
        noise = np.random.default_rng([change["prism_draw"], c.seed]).normal(0.0, c.prism_noise, exact.shape)
        return dataclasses.replace(data, prism_positions=exact + noise)
    s = data.odom.stamps
    T = Scenario(dataclasses.replace(c, **change)).odom_T_base(sc.true_time(s))
    return dataclasses.replace(data, odom=Trajectory(s, T[:, :3, 3], matrix_to_quat(T[:, :3, :3])))


def pass_information(seeds) -> None:
    print("\n## information: the network with one of the instruments' errors taken out of the recording")
    print(f"{'case':>28} {'≤5 mm (≥3 m base)':>18} {'z≤3':>7}  misses: seed/marker |error| mm (along its "
          f"worst axis, its σ there; the rest)")
    for name, change in INFORMATION:
        base, honest, mapped, misses = 0, 0, 0, []
        for seed in seeds:
            scen = scenario_dir(dataclasses.replace(PRESETS["demo"], seed=seed), "mapping", ARGS.workers)
            res, _ = network(scen, data=None if change is None else without(scen, change))
            hidden = hidden_of(scen)
            for m, e in zip(res.with_status("mapped"), errors(res, hidden)):
                mapped += 1
                honest += e[3] <= 3.0
                base += e[4] >= 3.0
                if e[4] >= 3.0 and e[1] > 5.0:
                    d = 1e3 * (m.position - np.array(hidden["marker_positions"][m.id]))
                    axes, dirs = m.ellipsoid(1.0)
                    along = float(d @ dirs[0])
                    misses.append(f"{seed}/{m.id} {e[1]:.1f} ({along:+.1f}, {1e3 * axes[0]:.1f}; "
                                  f"{np.linalg.norm(d - along * dirs[0]):.1f})")
        print(f"{name:>28} {base - len(misses):>12}/{base:<5} {honest:>3}/{mapped:<3}  {'; '.join(misses)}",
              flush=True)


def pass_scale() -> None:
    from unit.mapping.common import recording

    print("\n## scale: 50 markers, 10 minutes (the generator's exact bearings, 0.02° noise)")
    for every in (3, 1):
        sc = Scenario(dataclasses.replace(PRESETS["demo"], seed=7, duration=600.0, n_markers=50, world="open",
                                          profile="realistic"))
        rec, corners = recording(sc, every=every)
        tracemalloc.start()
        t0, w0 = time.process_time(), time.perf_counter()
        res = map_markers(rec, corners, size=0.19, readout=sc.config.rolling_shutter_readout)
        cpu, wall = time.process_time() - t0, time.perf_counter() - w0
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        print(f"  every {every}: {len(rec.obs_ids)} sightings, {len(res.with_status('mapped'))} of "
              f"{len(res.markers)} markers mapped: {cpu:.1f} s CPU ({wall:.0f} s wall), peak memory "
              f"{peak / 2 ** 20:.0f} MB (numpy arrays, tracemalloc); load {os.getloadavg()[0]:.1f}", flush=True)
        del rec, corners, res


def bearing_errors(scen: str) -> dict:
    """Per sighting of a map marker, against the truth (see the bearings pass): range (m), error across the sight
    line, horizontal and vertical (rad), the detection's σ (rad), azimuth from the front lens's axis (rad), marker
    id and row (v/H − ½)."""
    (obs, _), hidden = observations(scen), hidden_of(scen)
    cal, truth = load_calibration(true_calibration(scen)), read_tum(os.path.join(scen, "truth.tum"))
    # the stamp's true time, and the row's capture time after it
    t = Scenario.from_hidden(os.path.join(scen, "hidden.yaml")).true_time(obs.times) \
        + np.asarray(obs.rows) * float(cal["readout"])
    T, valid = truth.transforms_at(t)
    ids = np.asarray(obs.ids)
    known = valid & np.isin(ids, list(hidden["marker_positions"]))
    Tc = T[known] @ cal["camera"]
    bearings = np.asarray(obs.bearings)[known]
    o, w = cal["lenses"].marker_rays(bearings, np.asarray(obs.corners)[known])
    origins = Tc[:, :3, 3] + np.einsum("nij,nj->ni", Tc[:, :3, :3], o)
    seen = np.einsum("nij,nj->ni", Tc[:, :3, :3], w)
    to = np.array([hidden["marker_positions"][int(i)] for i in ids[known]]) - origins
    rng = np.linalg.norm(to, axis=1)
    to /= rng[:, None]
    across = np.cross([0.0, 0.0, 1.0], to)
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    e = seen - to
    return {"range": rng, "horizontal": np.sum(e * across, axis=1),
            "vertical": np.sum(e * np.cross(to, across), axis=1), "sigma": np.asarray(obs.sigmas)[known],
            "azimuth": np.arctan2(bearings[:, 1], bearings[:, 0]) - cal["lenses"].axis_azimuth, "id": ids[known],
            "row": np.asarray(obs.rows)[known]}


def pass_bearings(seeds) -> None:
    print("\n## bearings: each sighting against the truth (mdeg: thousandths of a degree)")
    runs = [bearing_errors(scenario_dir(dataclasses.replace(PRESETS["demo"], seed=seed), "mapping", ARGS.workers))
            for seed in seeds]
    e = {k: np.concatenate([r[k] for r in runs]) for k in runs[0]}
    seam = np.abs(np.cos(e["azimuth"])) < math.sin(math.radians(6.0))   # within 6° of the lenses' seams
    mdeg = 1e3 * 180.0 / math.pi
    print(f"{'sightings':>22} {'n':>6} {'sd horizontal':>14} {'sd vertical':>12} {'median σ':>9} {'sd / σ':>7}")
    for lo, hi in ((0, 4.5), (4.5, 8), (8, 20)):
        for name, part in (("off the seams", ~seam), ("at the seams", seam)):
            s = (e["range"] >= lo) & (e["range"] < hi) & part
            if s.sum() < 20:
                continue
            sd = np.std(e["horizontal"][s]), np.std(e["vertical"][s])
            sig = float(np.median(e["sigma"][s]))
            print(f"{f'{lo:g}-{hi:g} m, {name}':>22} {s.sum():>6} {mdeg * sd[0]:>14.1f} {mdeg * sd[1]:>12.1f} "
                  f"{mdeg * sig:>9.1f} {max(sd) / sig:>7.1f}")
    mid = np.abs(e["row"]) < 0.005
    print(f"{mid.sum()} sightings on the frame's middle rows (captured at a true pose's stamp: no interpolation): "
          f"sd horizontal {mdeg * np.std(e['horizontal'][mid]):.1f}, vertical {mdeg * np.std(e['vertical'][mid]):.1f}")
    means = [(np.mean(r["horizontal"][r["id"] == i]), np.mean(r["vertical"][r["id"] == i]))
             for r in runs for i in np.unique(r["id"])]
    print(f"each marker's mean error (its sightings' common part), RMS over {len(means)} markers: horizontal "
          f"{mdeg * math.sqrt(np.mean(np.square(means)[:, 0])):.1f}, vertical "
          f"{mdeg * math.sqrt(np.mean(np.square(means)[:, 1])):.1f} mdeg", flush=True)


def main(argv=None) -> int:
    global ARGS
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(101, 111)))
    ap.add_argument("--passes", nargs="+",
                    choices=("rendered", "control", "compare", "bearings", "information", "scale"),
                    default=["rendered", "control", "compare", "scale"])
    ap.add_argument("--workers", type=int, default=2)
    ARGS = ap.parse_args(argv)
    print(f"# bench/mapping.py: seeds {ARGS.seeds}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs",
          flush=True)
    for name in ARGS.passes:
        {"rendered": lambda: pass_rendered(ARGS.seeds), "control": lambda: pass_control(ARGS.seeds),
         "compare": lambda: pass_compare(ARGS.seeds), "bearings": lambda: pass_bearings(ARGS.seeds),
         "information": lambda: pass_information(ARGS.seeds),
         "scale": pass_scale}[name]()
    return 0


if __name__ == "__main__":
    sys.exit(main())
