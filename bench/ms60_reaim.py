#!/usr/bin/env python3
"""MS60 re-aim after a pillar: how long after a hidden prism reappears its positions resume, with the re-aim at
the robot's predicted position and with the plain search, side by side.

Two strict simulated MS60s share one prism (same boot time, same track) and one tracker each: one is given a
prediction as the driver gets it from tf (the fused pose 3 cm off, 30 Hz, its two newest poses 0.2 s apart
extrapolated linearly), the other none. Once both are locked the prism is hidden ``--hidden`` s while the
platform drives on at ``--speed`` m/s, then shown; the figure is the time from its reappearance to the first new
position of each. Drives: ``crossing`` (a circle about the station, across the line of sight; the direction
with or against PowerSearch's clockwise sweep alternates with the seed) and ``radial`` (towards the station
along its line of sight); ``--distance`` is the prism's distance when it reappears. Prints one row per case and
a summary per drive and distance; "never" is no position within ``--wait`` s.

    python bench/ms60_reaim.py                                   # 5-100 m, both drives, 2 seeds
    python bench/ms60_reaim.py --distances 5,20 --drives crossing --seeds 4
    python bench/ms60_reaim.py --lock-in 0.3                     # how much of the time is the lock-in's
"""
import argparse
import math
import statistics
import sys
import time

import numpy as np

from aruco_abs_orient.geocom.simulator import Ms60Simulator, SimConfig
from aruco_abs_orient.geocom.tracker import Ms60Tracker, TrackerConfig, extrapolate

HIDE_AT_S = 6.0     # host s after the simulators' boot when the prism is hidden (both trackers locked by then), plus
HIDE_SPREAD_S = 0.5  # up to this, by the seed: the loops' phases at the reappearance differ
POSE_RATE_HZ = 30.0  # the fused pose on tf
POSE_ERROR_M = 0.03  # its error


def track_of(drive: str, distance: float, speed: float, back: float, seed: int):
    """The prism's track (host s since boot → E, N, H m; the station at the origin, its axis at 0 m) and a
    description: at ``distance`` m when it reappears (``back`` s after boot), moving at ``speed`` m/s."""
    rng = np.random.default_rng(seed)
    azimuth, height = rng.uniform(0, 2 * math.pi), rng.uniform(-1.0, 1.0)
    if drive == "crossing":
        sense = 1.0 if seed % 2 else -1.0   # 1: clockwise (with PowerSearch's sweep), -1: against it

        def track(t):
            a = azimuth + sense * speed * (t - back) / distance
            return np.array([distance * math.sin(a), distance * math.cos(a), height])
        return track, "with the sweep" if sense > 0 else "against the sweep"

    def track(t):
        r = max(2.0, distance - speed * (t - back))
        return np.array([r * math.sin(azimuth), r * math.cos(azimuth), height * r / distance])
    return track, "towards the station"


def fused_pose_prediction(track, t_boot: float, seed: int):
    """``predict(t)`` as the driver's tf prediction: the two newest 30 Hz poses (3 cm off) extrapolated to t."""
    rng = np.random.default_rng(seed + 1000)
    bearing = rng.uniform(0, 2 * math.pi)
    error = POSE_ERROR_M * np.array([math.cos(bearing), math.sin(bearing), 0.0])

    def predict(at_s=None):
        now = time.time()
        t1 = math.floor(now * POSE_RATE_HZ) / POSE_RATE_HZ
        poses = [(t, track(t - t_boot) + error) for t in (t1 - 0.2, t1)]
        p = extrapolate(poses[0], poses[1], now, 1.0, at_s)
        return None if p is None else tuple(float(x) for x in p)
    return predict


def run_case(drive: str, distance: float, seed: int, args) -> dict:
    """One case: both instruments, the prism hidden and shown; the seconds to the first position of each."""
    hide_at = HIDE_AT_S + HIDE_SPREAD_S * np.random.default_rng(seed + 2000).uniform()
    track, how = track_of(drive, distance, args.speed, hide_at + args.hidden, seed)
    sims = [Ms60Simulator(SimConfig(lock_in_s=args.lock_in), track=track, seed=seed * 10 + k) for k in range(2)]
    for sim in sims[1:]:
        sim.t_boot = sims[0].t_boot
    t_boot = sims[0].t_boot
    arrivals = ([], [])
    trackers = [Ms60Tracker(TrackerConfig(f"socket://127.0.0.1:{sim.serve_tcp(0)}", warmup_samples=10,
                                          min_latency_s=SimConfig().min_latency_s,
                                          turn_rate_deg_s=args.turn_rate),
                            on_sample=lambda s, k=k: arrivals[k].append(time.time()),
                            predict=fused_pose_prediction(track, t_boot, seed) if k == 0 else None)
                for k, sim in enumerate(sims)]
    for tracker in trackers:
        tracker.start()
    try:
        time.sleep(max(0.0, t_boot + hide_at - time.time()))
        locked = all(len(a) > 10 for a in arrivals)
        for sim in sims:
            sim.set_prism_visible(False)
        time.sleep(args.hidden)
        t_back = time.time()
        for sim in sims:
            sim.set_prism_visible(True)
        while time.time() < t_back + args.wait and not all(any(t > t_back for t in a) for a in arrivals):
            time.sleep(0.02)
        stats = trackers[0].stats()
    finally:
        for tracker, sim in zip(trackers, sims):
            tracker.stop()
            sim.close()
    resumed = [next((t - t_back for t in a if t > t_back), None) for a in arrivals]
    return {"drive": drive, "distance": distance, "seed": seed, "how": how, "locked": locked,
            "reaim": resumed[0], "search": resumed[1], "reaims": stats.reaims, "found": stats.reaims_found}


def _fmt(t) -> str:
    return "never" if t is None else f"{t:5.2f} s"


def summary(rows) -> None:
    """Median and worst of both ways per drive and distance ("never" counts as worst)."""
    print("\ndrive     distance  re-aim median / worst   search median / worst")
    for drive in sorted({r["drive"] for r in rows}):
        for distance in sorted({r["distance"] for r in rows if r["drive"] == drive}):
            part = [r for r in rows if r["drive"] == drive and r["distance"] == distance]
            cells = []
            for way in ("reaim", "search"):
                times = [r[way] for r in part]
                known = [t for t in times if t is not None]
                median = statistics.median(known) if known else None
                worst = None if None in times else max(times)
                cells.append(f"{_fmt(median)} / {_fmt(worst)}")
            print(f"{drive:9s} {distance:6.0f} m  {cells[0]:22s}  {cells[1]}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--distances", default="5,20,50,100", help="m, comma-separated (default 5,20,50,100)")
    parser.add_argument("--drives", default="crossing,radial", help="crossing and/or radial")
    parser.add_argument("--seeds", type=int, default=2, help="cases per drive and distance (default 2)")
    parser.add_argument("--speed", type=float, default=1.0, help="platform speed, m/s (default 1)")
    parser.add_argument("--hidden", type=float, default=2.0, help="seconds behind the pillar (default 2)")
    parser.add_argument("--turn-rate", type=float, default=TrackerConfig("x").turn_rate_deg_s,
                        help="the tracker's turn rate, °/s (the simulator turns at "
                             f"{math.degrees(SimConfig().slew_rad_s):.0f} °/s)")
    parser.add_argument("--lock-in", type=float, default=SimConfig().lock_in_s,
                        help="the simulated AUT_LockIn's duration, s (default %(default)s)")
    parser.add_argument("--wait", type=float, default=12.0, help="s to wait for positions after reappearing")
    args = parser.parse_args()
    c = SimConfig(lock_in_s=args.lock_in)
    print(f"simulated MS60: AUT_MakePositioning {c.positioning_s} s + {math.degrees(c.slew_rad_s):.0f} °/s, "
          f"AUT_FineAdjust {c.fine_adjust_s} s, AUT_LockIn {c.lock_in_s} s, PowerSearch {c.power_search_s} s "
          f"a turn, EDM {c.edm_rate_hz:.0f} Hz; prism hidden {args.hidden} s at {args.speed} m/s")
    print("drive     distance  seed  re-aim    search    re-aims found  motion")
    rows = []
    for drive in args.drives.split(","):
        for distance in (float(d) for d in args.distances.split(",")):
            for seed in range(1, args.seeds + 1):
                r = run_case(drive, distance, seed, args)
                rows.append(r)
                print(f"{drive:9s} {distance:6.0f} m  {seed:4d}  {_fmt(r['reaim'])}  {_fmt(r['search'])}  "
                      f"{r['reaims']:7d} {r['found']:5d}  {r['how']}{'' if r['locked'] else ' (NOT LOCKED before)'}",
                      flush=True)
    summary(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
