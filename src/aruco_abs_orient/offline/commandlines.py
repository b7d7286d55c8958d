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

__all__ = ["calibrate_command", "process_command"]


def process_command(bag: Bags, markers: str, time_offset: float, calibration: Optional[str] = None) -> str:
    """The ``process`` command line that follows ``calibrate`` (printed after ``use:``): the bag(s), marker map
    (``markers`` already shell-quoted) and ``calibration`` as given, the output in ``results/<bag name>``."""
    stem = os.path.splitext(os.path.basename(bag_name(bag)))[0] or "run"
    cmd = (f"aruco-abs-orient process {bags_for_shell(bag)} --markers {markers} "
           f"--out {shlex.quote('results/' + stem)} --time-offset {time_offset:.4f}")
    return cmd + (f" --calibration {shlex.quote(calibration)}" if calibration else "")


def calibrate_command(bag: Bags, markers: Optional[str], time_offset: float) -> str:
    """The ``calibrate`` command line that follows ``timesync`` (printed after ``use:``): the bag(s) and marker map
    as given (``markers`` None: a placeholder), the offset refined there, ``--out`` beside the marker map."""
    where = os.path.join(os.path.dirname(markers), "calibration.yaml") if markers else "calibration.yaml"
    return (f"aruco-abs-orient calibrate {bags_for_shell(bag)} --markers "
            f"{shlex.quote(markers) if markers else '<markers.yaml>'} --time-offset {time_offset:.4f} "
            f"--refine-time-offset --every 3 --out {shlex.quote(where)}")
