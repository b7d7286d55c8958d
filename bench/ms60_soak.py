#!/usr/bin/env python3
"""MS60 fault soak: the tracker against the strict simulator (LOCK mode, fine adjust and a 1.2 s
lock-in, a 20 Hz EDM) on a pty (or local TCP) with random faults.

Prints the achieved rate of fresh positions (a distance published once) and the theoretical limit
from the bytes per request at the baud rate, the timestamp error vs the simulator's truth
(median/p95/max, with ±10 ms latency jitter), lost samples and recoveries (time from link/prism
back to the next published sample), and the same error for naive reception-time stamps. Asserts: no
crash, no duplicate, no out-of-order stamp, every published position equal to the truth (to the
6 decimals of COM_SetDoublePrecision), no internal error of the simulator. Motorised calls get a
5 s timeout here: the simulator's random drops also drop their replies, which a real instrument's
link does not do every few minutes.

    python bench/ms60_soak.py --seconds 120            # the 2-minute soak
    python bench/ms60_soak.py --seconds 20 --tcp --no-faults
"""
import argparse
import sys
import threading
import time

import numpy as np

from aruco_abs_orient.geocom.client import wire_time_s
from aruco_abs_orient.geocom.protocol import TMC_AUTO_INC, Rpc, encode_reply, encode_request
from aruco_abs_orient.geocom.simulator import FaultRates, Ms60Simulator, SimConfig
from aruco_abs_orient.geocom.tracker import Ms60Tracker, TrackerConfig


def _arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=120.0, help="soak duration (default 120 s)")
    parser.add_argument("--baud", type=int, default=115200)
    parser.add_argument("--tcp", action="store_true", help="local TCP instead of a pty")
    parser.add_argument("--no-faults", action="store_true", help="clean link (rate and stamp figures only)")
    parser.add_argument("--seed", type=int, default=2024)
    return parser.parse_args()


def _soak(args: argparse.Namespace):
    """Run the tracker against the simulator for ``args.seconds``: (simulator, its config, the (reception time,
    sample) pairs, the tracker's stats, the seconds it ran)."""
    faults = FaultRates() if args.no_faults else FaultRates(
        garbage=0.02, drop=0.01, late=0.003, warning=0.03, spike=0.02, lock_loss=0.03, link_loss=0.03)
    config = SimConfig(baud=args.baud, latency_s=0.012, jitter_s=0.010, faults=faults)
    sim = Ms60Simulator(config, seed=args.seed)
    url = f"socket://127.0.0.1:{sim.serve_tcp(0)}" if args.tcp else sim.serve_pty()
    samples, lock = [], threading.Lock()

    def on_sample(s):
        with lock:
            samples.append((time.time(), s))

    tracker = Ms60Tracker(TrackerConfig(url, baud=args.baud, rate_hz=20.0, min_latency_s=config.min_latency_s,
                                        motion_timeout_s=5.0), on_sample=on_sample)
    t_start = time.time()
    tracker.start()
    try:
        while time.time() - t_start < args.seconds:
            time.sleep(min(5.0, args.seconds - (time.time() - t_start)) if args.seconds > 0 else 0)
            with lock:
                n = len(samples)
            print(f"  {time.time() - t_start:6.1f} s  {n} samples  state {tracker.state.value}", file=sys.stderr)
    finally:
        tracker.stop()
        sim.close()
    elapsed = time.time() - t_start
    return sim, config, samples, tracker.stats(), elapsed


def _wire_limits(baud: int, latency_s: float):
    """The theoretical rate limit (Hz) from the request + reply bytes of one TMC_GetCoordinate at ``baud``, the
    same with the mean latency, and the bytes."""
    request = encode_request(Rpc.TMC_GetCoordinate, (0, TMC_AUTO_INC), 9999)
    reply = encode_reply(0, (1234.567891, -2345.678912, 345.678912, 2**31, 1234.567891, -2345.678912,
                             345.678912, 2**31), 0, 9999)
    wire = wire_time_s(len(request) + len(reply), baud)
    return 1.0 / wire, 1.0 / (wire + latency_s), len(request) + len(reply)


def _checked_stamp_errors(sim, samples):
    """Assert the stream is clean (stamps increasing, no duplicate, positions equal to the truth, no internal
    error); the stamps' absolute errors and the reception times' delays against the truth (ms)."""
    truth = {r.instrument_ms: r for r in sim.truth if r.instrument_ms >= 0}
    stamps = np.array([s.stamp_s for _, s in samples])
    assert np.all(np.diff(stamps) > 0), "out-of-order or duplicate stamp"
    assert len({s.instrument_ms for _, s in samples}) == len(samples), "duplicate sample"
    assert sim.internal_errors == [], sim.internal_errors
    err, naive = [], []
    for rx, s in samples:
        r = truth[s.instrument_ms]
        assert np.allclose((s.east, s.north, s.height), r.position, atol=0.6e-6), "position differs from the truth"
        err.append((s.stamp_s - r.time_s) * 1e3)
        naive.append((rx - r.time_s) * 1e3)
    return np.abs(np.array(err)), np.array(naive)


def _recoveries(sim, samples):
    """Seconds from each link or prism back to the next sample received."""
    recoveries = []
    for t0, kind, t_end in sim.events:
        if kind in ("link_down", "prism_visible"):
            back = t_end if kind == "link_down" else t0
            first = next((rx for rx, _ in samples if rx > back), None)
            if first is not None:
                recoveries.append(first - back)
    return recoveries


def main() -> int:
    args = _arguments()
    sim, config, samples, stats, elapsed = _soak(args)
    limit_hz, limit_lat_hz, n_bytes = _wire_limits(args.baud, config.latency_s)
    err, naive = _checked_stamp_errors(sim, samples)
    recoveries = _recoveries(sim, samples)
    rec = np.array(recoveries) if recoveries else np.array([float("nan")])
    rx_times = [rx for rx, _ in samples]
    steady_rate = (len(rx_times) - 1) / (rx_times[-1] - rx_times[0]) if len(rx_times) > 1 else 0.0

    print(f"MS60 soak: {elapsed:.1f} s over {'TCP' if args.tcp else 'pty'} at {args.baud} baud, "
          f"latency {config.latency_s * 1e3:.0f}±{config.jitter_s * 1e3:.0f} ms, "
          f"faults {'off' if args.no_faults else 'on'}")
    print(f"  rate: {len(samples) / elapsed:.2f} Hz published overall (20 Hz requested); "
          f"theoretical limit {limit_hz:.1f} Hz from {n_bytes} bytes per request "
          f"({limit_lat_hz:.1f} Hz with the mean latency)")
    print(f"  sustained rate from the first to the last sample: {steady_rate:.2f} Hz")
    print(f"  stamp error vs truth: median {np.median(err):.2f} ms, p95 {np.percentile(err, 95):.2f} ms, "
          f"max {err.max():.2f} ms (naive reception stamps: median {np.median(naive):.1f} ms late, "
          f"max {naive.max():.1f} ms)")
    print(f"  EDM period {stats.edm_period_ms:.1f} ms; repeated distances polled and not published: "
          f"{stats.duplicates}; program {stats.program}, search {stats.search or '-'}")
    print(f"  samples {stats.samples}, lost {stats.lost_samples}, warnings {stats.warnings}, "
          f"no position {stats.no_position}, timeouts {stats.timeouts}, garbage bytes {stats.garbage_bytes}, "
          f"stale replies {stats.stale_replies}")
    print(f"  faults injected: {sum(1 for e in sim.events if e[1] == 'link_down')} link outages, "
          f"{sum(1 for e in sim.events if e[1] == 'prism_hidden')} lock losses; reconnects {stats.reconnects}, "
          f"relocks {stats.relocks}")
    print(f"  recovery after link/prism back: median {np.median(rec):.2f} s, max {np.max(rec):.2f} s "
          f"over {len(recoveries)} events")
    print(f"  clock: drift {stats.clock_drift * 1e6:.1f} ppm (simulated {-config.clock_drift * 1e6:.1f} ppm)")
    print("  checks: no crash, no duplicate, no out-of-order, positions equal to truth: OK")
    return 0


if __name__ == "__main__":
    sys.exit(main())
