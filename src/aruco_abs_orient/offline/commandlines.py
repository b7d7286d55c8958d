"""The command lines the offline tools suggest as the next step (``use: …``), ready to paste into a shell.

In: the recording (a bag, split bags or a VideoRecording), the marker map path and the time offset (s) the
step found. Out: the ``calibrate`` line that follows ``timesync`` (:func:`calibrate_command`) and the
``process`` line that follows ``calibrate`` (:func:`process_command`), every path shell-quoted. ``process``'s
self-checks use them too, in the warnings that say which command fixes what they found.
"""

from __future__ import annotations

import os
import shlex
from typing import Optional

from .bagio import Bags, bag_name, bags_for_shell

__all__ = ["calibrate_command", "calibration_every", "process_command"]


def process_command(bag: Bags, markers: str, time_offset: float, calibration: Optional[str] = None) -> str:
    """The ``process`` command line that follows ``calibrate`` (printed after ``use:``): the bag(s), marker map
    (``markers`` already shell-quoted) and ``calibration`` as given, the output in ``results/<bag name>``."""
    stem = os.path.splitext(os.path.basename(bag_name(bag)))[0] or "run"
    cmd = (f"aruco-abs-orient process {bags_for_shell(bag)} --markers {markers} "
           f"--out {shlex.quote('results/' + stem)} --time-offset {time_offset:.4f}")
    return cmd + (f" --calibration {shlex.quote(calibration)}" if calibration else "")


#: images per second worth detecting for a calibration: more, a few cm apart, add detection time, not precision
CALIBRATION_RATE = 10.0


def calibration_every(image_rate: float) -> int:
    """Every how many images of a recording of ``image_rate`` images/s (0: unknown → 1) to detect for a
    calibration or a time offset: about :data:`CALIBRATION_RATE` a second."""
    return max(1, round(image_rate / CALIBRATION_RATE))


def calibrate_command(bag: Bags, markers: Optional[str], time_offset: float, image_rate: float = 0.0) -> str:
    """The ``calibrate`` command line that follows ``timesync`` (printed after ``use:``): the bag(s) and marker map
    as given (``markers`` None: a placeholder), the offset refined there, ``--out`` beside the marker map, and for
    a recording of ``image_rate`` images/s (0: unknown) ``--every`` keeping about :data:`CALIBRATION_RATE` of
    them a second."""
    where = os.path.join(os.path.dirname(markers), "calibration.yaml") if markers else "calibration.yaml"
    every = calibration_every(image_rate)
    return (f"aruco-abs-orient calibrate {bags_for_shell(bag)} --markers "
            f"{shlex.quote(markers) if markers else '<markers.yaml>'} --time-offset {time_offset:.4f} "
            f"--refine-time-offset{f' --every {every}' if every > 1 else ''} --out {shlex.quote(where)}")
