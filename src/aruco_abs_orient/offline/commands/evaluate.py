"""``aruco-abs-orient evaluate``: the report of a processed run (the arguments).

In: a ``process`` output directory, optionally a reference trajectory, the fused output of a replay, a frame of
the recording for the overview and a params file. Out: what :func:`aruco_abs_orient.offline.evaluate.evaluate_run`
writes (report.md, report.json, the plots), its headline figures as lines and its self-check notes on stderr.
Exit status: 0 written, 2 bad input.
"""

from __future__ import annotations

import argparse
import os
import sys

from ...errors import ConfigurationError
from ...markers import MarkerMap
from ...params import load_params
from ..evaluate import parse_after
from ..options import add_params_option

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "evaluate", help="report of a processed run: markers agree?, residuals, coverage; errors vs a reference",
        description="The report of a processed run (report.md: a page of headline figures beside the paper's, "
                    "the plots, then tables per marker; report.json; PNG plots). Without --reference it shows what "
                    "the run shows by itself, the paper's own evaluation: the markers' yaws against each other "
                    "(pairwise, per-marker trajectories, paper figs. 11-12), the residuals and their sigma "
                    "consistency, coverage and gaps, and the run's self-checks. With --reference (a TUM "
                    "trajectory of base_link in map) it adds the heading and position errors (and fig. 13).",
        epilog="examples:\n  aruco-abs-orient evaluate results/run1\n"
               "  aruco-abs-orient evaluate results/run1 --reference truth.tum --overview run1.bag markers.yaml\n"
               "  aruco-abs-orient evaluate results/run1 --reference truth.tum --fused results/run1_out.bag --after 5\n"
               "  aruco-abs-orient evaluate results/run1 --reference truth.tum --params my_params.yaml",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", help="output directory of `process` (summary.json, trajectory.tum, observations.csv)")
    p.add_argument("--reference", metavar="TUM", help="TUM file of base_link in map (e.g. a simulation's truth): "
                   "adds the errors against it")
    p.add_argument("--out", help="report directory (default: the run directory)")
    p.add_argument("--fused", metavar="BAG", help="with --reference: also judge /odometry/filtered "
                   "(robot_localization) recorded in BAG by postprocess.launch record:=BAG")
    p.add_argument("--fused-clock-offset", type=float, metavar="S",
                   help="the recorded stamps are on the camera clock: subtract S s (default: the time offset the "
                        "run used, from its summary.json)")
    p.add_argument("--after", type=parse_after, metavar="T",
                   help="judge the fused output from T s after the start of the recording on (e.g. 5), or from "
                        "an absolute total-station stamp with the suffix abs (e.g. 1700000000.5abs); default: "
                        "1 s after its first absolute yaw")
    p.add_argument("--overview", nargs=2, metavar=("BAG_OR_VIDEO", "MARKERS"),
                   help="also draw overview.png (first in the report): a frame of the bag or video (.mp4, .mov, "
                        ".mkv) with its markers above the trajectory")
    add_params_option(p, "evaluation section (the gaps no error is interpolated across, the coverage gaps "
                         "listed, the fused output's settling time)")
    p.set_defaults(handler=run)
    return p


def run(a: argparse.Namespace) -> int:
    """``evaluate``: 0 the report written, 2 bad input."""
    from ..evaluate import evaluate_run

    if a.fused and not a.reference:
        raise ConfigurationError("--fused needs --reference: the EKF's output is judged against a reference "
                                 "trajectory")
    params = load_params(a.params).evaluation
    overview = None
    if a.overview:
        from ..overview import overview_figure

        os.makedirs(a.out or a.run, exist_ok=True)
        overview = overview_figure(os.path.join(a.out or a.run, "overview.png"), a.overview[0], a.run, a.reference,
                                   MarkerMap.load(a.overview[1]))
    res = evaluate_run(a.run, a.reference, a.out, params, fused=a.fused, fused_clock_offset=a.fused_clock_offset,
                       after=a.after, overview=overview)
    for quantity, value, paper, _ in res["headline"]:
        print(f"{quantity}: {value}" + (f" (paper: {paper})" if paper != "–" else ""))
    for note in res["notes"]:
        print(f"aruco-abs-orient: check: {note.split(' ([')[0]}", file=sys.stderr)
    print(f"wrote {res['report_md']}\n      {res['report_json']}")
    return 0

