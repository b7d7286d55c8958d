"""``aruco-abs-orient-ms60-sim``: a simulated Leica MS60 (GeoCOM) on a pty or a local TCP port."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import List, Optional

from ..errors import run
from .instrument import MODELS, PROFILES, FaultRates, SimConfig, SimulatorError, builtin_track, tum_track
from .simulator import Ms60Simulator

__all__ = ["main", "parse_faults"]

EPILOG = """examples:
  aruco-abs-orient-ms60-sim --pty
      prints the pty path, e.g. /dev/pts/7; then: rosrun aruco_abs_orient ms60_driver _port:=/dev/pts/7
  aruco-abs-orient-ms60-sim --tcp 5025 --trajectory prism.tum --faults garbage=0.02,drop=0.01,lock_loss=0.05
      the driver connects with _port:=socket://127.0.0.1:5025
  aruco-abs-orient-ms60-sim --pty --model TPS1200 --profile lenient
      a forgiving TPS1200 without PowerSearch

profiles: strict (default) checks every parameter and refuses what the TPS1200+/Captivate GeoCOM
references refuse (TMC_DoMeasure program 2, a station while a distance exists, AUT_LockIn without LOCK
mode or fine adjustment); its lock-in takes --lock-in-s and its EDM measures at 20 Hz. lenient accepts
those and gives every poll a fresh distance.

faults (comma-separated name=value): garbage, drop, late, warning, spike (probability per reply);
lock_loss, link_loss (events per second, each lasting 0.3-1.5 s)."""


def parse_faults(text: str) -> FaultRates:
    """``"garbage=0.02,drop=0.01"`` → FaultRates. Raises SimulatorError naming the bad item."""
    rates = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        name, sep, value = item.partition("=")
        if not sep or name not in FaultRates._fields or name == "outage_s":
            raise SimulatorError(f"--faults: unknown item {item!r} (names: {', '.join(FaultRates._fields[:-1])})")
        try:
            v = float(value)
        except ValueError:
            raise SimulatorError(f"--faults: {name}={value!r} is not a number") from None
        if not v >= 0 or (name not in ("lock_loss", "link_loss") and v > 1):
            raise SimulatorError(f"--faults: {name}={v} out of range")
        rates[name] = v
    return FaultRates(**rates)


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point of ``aruco-abs-orient-ms60-sim``: the exit status (2: a bad option or trajectory, one line)."""
    return run("aruco-abs-orient-ms60-sim", lambda: _serve(argv))


def _serve(argv: Optional[List[str]]) -> int:
    parser = argparse.ArgumentParser(prog="aruco-abs-orient-ms60-sim", description=__doc__.replace("``", ""),
                                     epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pty", action="store_true", help="serve on a new pseudo-terminal (prints its path)")
    parser.add_argument("--tcp", type=int, metavar="PORT", help="serve on TCP 127.0.0.1:PORT (0: any free port)")
    parser.add_argument("--baud", type=int, default=115200, help="baud rate for the byte timing (default 115200)")
    parser.add_argument("--trajectory", metavar="TUM", help="prism trajectory, TUM file (default: built-in track)")
    parser.add_argument("--faults", default="", help="random faults, e.g. garbage=0.02,drop=0.01 (see below)")
    parser.add_argument("--latency-ms", type=float, default=12.0, help="mean reply latency, ms (default 12)")
    parser.add_argument("--jitter-ms", type=float, default=10.0, help="latency jitter ±, ms (default 10)")
    parser.add_argument("--drift-ppm", type=float, default=40.0, help="instrument clock drift, ppm (default 40)")
    parser.add_argument("--seed", type=int, default=None, help="random seed for jitter and faults")
    parser.add_argument("--profile", choices=PROFILES, default="strict", help="instrument behaviour (default strict)")
    parser.add_argument("--model", choices=MODELS, default="MS60",
                        help="MS60 (PowerSearch, synchro tracking) or TPS1200 (neither); default MS60")
    parser.add_argument("--lock-in-s", type=float, default=SimConfig().lock_in_s,
                        help=f"duration of AUT_LockIn, s (default {SimConfig().lock_in_s})")
    parser.add_argument("--truth", metavar="CSV", help="write the truth log here on exit (t_s,instrument_ms,x,y,z,rc)")
    args = parser.parse_args(argv)
    if args.pty == (args.tcp is not None):
        parser.error("choose exactly one of --pty and --tcp PORT")
    faults = parse_faults(args.faults)
    config = SimConfig(baud=args.baud, latency_s=args.latency_ms / 1000.0, jitter_s=args.jitter_ms / 1000.0,
                       clock_drift=args.drift_ppm * 1e-6, faults=faults, profile=args.profile, model=args.model,
                       lock_in_s=args.lock_in_s, name="MS60" if args.model == "MS60" else "TCRP1201+")
    track = tum_track(args.trajectory) if args.trajectory else builtin_track
    sim = Ms60Simulator(config, track, seed=args.seed)
    # Ctrl-C and SIGTERM stop it from the moment it serves (a KeyboardInterrupt between announcing the port and
    # waiting would skip close(), and its serving thread would keep the process alive)
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    try:
        where = sim.serve_pty() if args.pty else f"socket://127.0.0.1:{sim.serve_tcp(args.tcp)}"
        print(where, flush=True)
        print(f"{args.model} simulator ({args.profile}) at {args.baud} baud, "
              f"latency {args.latency_ms}±{args.jitter_ms} ms; Ctrl-C to stop", file=sys.stderr, flush=True)
        while not done.wait(0.5):
            pass
    finally:
        sim.close()
    if args.truth:
        from ..tum import atomic_write_text

        atomic_write_text(args.truth, "t_s,instrument_ms,x,y,z,rc,sent\n" + "".join(
            f"{r.time_s:.6f},{r.instrument_ms},{r.position[0]:.6f},{r.position[1]:.6f},{r.position[2]:.6f},"
            f"{r.rc},{int(r.sent)}\n" for r in sim.truth))
    return 0


if __name__ == "__main__":
    sys.exit(main())
