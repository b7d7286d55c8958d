"""One error family for the package: every error it raises on purpose is an :class:`AbsOrientError`.

In: nothing. Out: the base class and one subclass per area, which the modules' own error classes
(``DetectionError``, ``BagError``, ``SolverError``, …) derive from, keeping their names and
messages (what, where, what was expected). A caller that only reports and stops (the CLI) catches
:class:`AbsOrientError` once; a caller that handles one case catches that module's class. The
module classes that were ``ValueError`` / ``RuntimeError`` subclasses still are, so older
``except ValueError`` callers behave as before.
"""

from __future__ import annotations

__all__ = ["AbsOrientError", "InputFileError", "BagFileError", "GeometryError", "InstrumentError",
           "ConfigurationError"]


class AbsOrientError(Exception):
    """Base of every error this package raises on purpose."""


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
