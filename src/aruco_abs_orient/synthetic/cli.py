"""``aruco-abs-orient-synth``: render a synthetic scenario into a ROS 1 bag plus its truth files."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import List, Optional

from ..errors import run
from .bag import describe, generate
from .scenario import PRESETS

EXAMPLE = """\
outputs (in --out): scenario.bag (/camera/image/compressed, /tf, /tf_static, /ms60/prism),
truth.tum (base_link in map at each image's true time), markers.yaml, hidden.yaml.

presets, the easy world (a textured panorama; quick, for tests):
         tiny (8 s, 10 fps, 960x480), ci (20 s, 15 fps, 1920x960),
         easy (60 s, 30 fps, 3840x1920), bench (like easy, 10 s unless --duration)
       the realistic world (a hall with pillars, posters, lights; wander, exposure, blur, JPEG 85,
       a stitch seam, a 20 ppm camera clock; see hidden.yaml for every parameter):
         demo (60 s, 30 fps, 3840x1920, a 30 ms rolling shutter),
         realistic (20 s, global shutter), realistic-rs (realistic with a 30 ms rolling shutter)

example:
  aruco-abs-orient-synth --preset demo --seed 7 --time-offset 0.367 --out /tmp/demo
"""


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit 2)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


def _positive(kind):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not {'an integer' if kind is int else 'a number'}: {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
        return value
    return parse


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="aruco-abs-orient-synth", description=__doc__.strip().replace("``", ""), epilog=EXAMPLE,
                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", choices=sorted(PRESETS), default="ci", help="base parameters (default: ci)")
    p.add_argument("--seed", type=_non_negative_int, help="random seed (default 0)")
    p.add_argument("--duration", type=_positive(float), help="seconds of images")
    p.add_argument("--fps", type=_positive(float), help="camera frame rate, Hz")
    p.add_argument("--width", type=_positive(int), help="equirect width in px (even; height = width/2)")
    p.add_argument("--time-offset", type=_float, help="camera/VO clock minus true time, s (default 0.367)")
    p.add_argument("--boresight-deg", type=_float, help="unpublished camera rotation error, deg (default 0.3)")
    p.add_argument("--readout", type=_float, metavar="S",
                   help="rolling shutter readout, s (0-0.04; row v at stamp + (v/H - 1/2) * readout)")
    p.add_argument("--jpeg-quality", type=_positive(int), help="JPEG quality of the images, 1-100")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs in DIR")
    p.add_argument("--workers", type=_positive(int), default=2, help="render processes (default 2)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point of ``aruco-abs-orient-synth``: the exit status (2: a bad option or output, one line; 130:
    interrupted, no bag written)."""
    args = build_parser().parse_args(argv)
    return run("aruco-abs-orient-synth", lambda: _generate(args))


def _generate(args: argparse.Namespace) -> int:
    overrides = {name: value for name, value in (
        ("seed", args.seed), ("duration", args.duration), ("fps", args.fps), ("width", args.width),
        ("camera_time_offset", args.time_offset), ("boresight_deg", args.boresight_deg),
        ("rolling_shutter_readout", args.readout), ("jpeg_quality", args.jpeg_quality)) if value is not None}
    config = dataclasses.replace(PRESETS[args.preset], **overrides).validate()
    result = generate(config, args.out, progress=not args.quiet, force=args.force, workers=args.workers)
    print(describe(result, config))
    return 0


if __name__ == "__main__":
    sys.exit(main())
