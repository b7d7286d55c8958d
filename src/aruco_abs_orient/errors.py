"""One error family for the package, and the one place where an error meets the user.

In: nothing. Out: :class:`AbsOrientError` and one subclass per area, which the modules' own error classes
(``DetectionError``, ``BagError``, ``SolverError``, …) derive from; and :func:`run`, the error boundary of
every console script and node. Every error the package raises on purpose is an :class:`AbsOrientError` whose
message names the file, field or option, what was wrong and what was expected. A caller that handles one case
catches that module's class; nothing but :func:`run` catches them all.

Contract of :func:`run`: ``main()``'s return value is the exit status; an :class:`AbsOrientError` (or an
``OSError`` of a file) becomes one line ``<prog>: error: <message>`` and its class's :attr:`exit_status`
(2: bad input or configuration, 1: the input does not give the answer), Ctrl-C exits 130; never a traceback.
"""

from __future__ import annotations

import sys
from typing import Callable, Optional

__all__ = ["AbsOrientError", "InputFileError", "BagFileError", "GeometryError", "InstrumentError",
           "ConfigurationError", "NoResultError", "run", "one_line"]


class AbsOrientError(Exception):
    """Base of every error this package raises on purpose."""

    #: the exit status of a command that stops on it
    exit_status = 2


class InputFileError(AbsOrientError):
    """A file or record read or written (marker map, TUM file, image, message, output directory) is unusable."""


class BagFileError(AbsOrientError):
    """A ROS bag cannot be read or lacks what is needed (topics, messages, stamps)."""


class GeometryError(AbsOrientError):
    """The geometry does not determine the answer (degenerate markers, no overlap, no motion)."""


class InstrumentError(AbsOrientError):
    """The total station, its link, protocol, clock or simulator failed or refused."""


class ConfigurationError(AbsOrientError):
    """A parameter, argument or option has a wrong name, type or value."""


class NoResultError(AbsOrientError):
    """The inputs were read, but they do not give what was asked for (a time offset, a calibration): why."""

    exit_status = 1


def one_line(error: BaseException) -> str:
    """The message of ``error`` on one line; an OSError as ``<file>: <reason>``."""
    if isinstance(error, OSError) and error.strerror:
        text = f"{error.filename}: {error.strerror}" if error.filename else error.strerror
    else:
        text = str(error) or type(error).__name__
    return " ".join(text.split())


def run(prog: str, main: Callable[[], Optional[int]],
        report: Optional[Callable[[str, int], int]] = None) -> int:
    """The exit status of ``main()`` (None: 0); an AbsOrientError or OSError it raises becomes one line and a
    non-zero status: ``report(message, status)`` when given (a node logs it), else ``<prog>: error: <message>``
    on stderr. Ctrl-C: ``<prog>: interrupted``, 130."""
    try:
        status = main()
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except (AbsOrientError, OSError) as e:
        status = e.exit_status if isinstance(e, AbsOrientError) else 2
        if report is not None:
            return report(one_line(e), status)
        print(f"{prog}: error: {one_line(e)}", file=sys.stderr)
        return status
    return 0 if status is None else int(status)
