"""One declaration per parameter, and the one check of every params class.

In: a params dataclass whose fields are declared with :func:`param` (default, meaning, unit, range or
choices, in one place) and derive from :class:`Params`. Out: the field's :class:`Spec` (:func:`spec_of`,
:func:`specs`), its value checked when the object is made or replaced (:meth:`Params.validate`: type, finite,
range, choices, then the class's own rules across fields in :meth:`Params.check_together`), a value read from
YAML or a ROS parameter as the field's type (:func:`coerce`), and the text of the range (:func:`describe_range`)
that cfg/params.yaml and cfg/AbsOrient.cfg show. Errors: the class's ``error`` (an AbsOrientError), one line
``Class.field: expected <range>, got <value>`` (:meth:`Params.label` names the field, a node's ``~name``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar, Dict, NamedTuple, Optional, Tuple, Type

from .errors import AbsOrientError, ConfigurationError

__all__ = ["Spec", "param", "Params", "spec_of", "specs", "coerce", "describe_range", "short_range", "expected_type",
           "problem"]


class Spec(NamedTuple):
    """What a parameter is: ``meaning`` (one line), ``unit`` ('' for counts, flags and ratios), the range
    ``low``/``high`` (inclusive; ``low_open``/``high_open``: exclusive), ``choices`` (the values allowed, instead
    of a range), ``optional`` (None is allowed: the feature off) and ``kind`` (the type of its values)."""

    meaning: str
    unit: str = ""
    low: Optional[float] = None
    high: Optional[float] = None
    low_open: bool = False
    high_open: bool = False
    choices: Tuple = ()
    optional: bool = False
    kind: type = float


def param(default, meaning: str, unit: str = "", low: Optional[float] = None, high: Optional[float] = None, *,
          above: Optional[float] = None, below: Optional[float] = None, choices: Tuple = (),
          optional: bool = False) -> Any:
    """A dataclass field with its :class:`Spec`: ``low``/``high`` inclusive bounds, ``above``/``below`` exclusive
    ones (for a tuple: of each element), ``choices`` the allowed values, ``optional``: None (null) is allowed too
    (the feature off). The kind of its values is the default's (a tuple: numbers)."""
    spec = Spec(meaning, unit, above if above is not None else low, below if below is not None else high,
                above is not None, below is not None, tuple(choices), optional, type(default))
    return dataclasses.field(default=default, metadata={"spec": spec})


def spec_of(cls, name: str) -> Spec:
    """The Spec of the field ``name`` of the params class ``cls``."""
    return next(f.metadata["spec"] for f in dataclasses.fields(cls) if f.name == name)


def specs(cls) -> Dict[str, Spec]:
    """name → Spec of every field of ``cls``, in order."""
    return {f.name: f.metadata["spec"] for f in dataclasses.fields(cls)}


def _number(x: float) -> str:
    return f"{x:g}"


def _bounds(spec: Spec) -> str:
    """The bounds as written: '[0, 0.2]', '(0, 90)', '≥ 1', '> 0', '≤ 5', or '' when there are none."""
    lo, hi = spec.low, spec.high
    if lo is not None and hi is not None:
        return f"{'(' if spec.low_open else '['}{_number(lo)}, {_number(hi)}{')' if spec.high_open else ']'}"
    if lo is not None:
        return f"{'>' if spec.low_open else '≥'} {_number(lo)}"
    if hi is not None:
        return f"{'<' if spec.high_open else '≤'} {_number(hi)}"
    return ""


def describe_range(spec: Spec) -> str:
    """What a value must be, for people: 'a number in [0, 0.2]', 'an integer ≥ 1', 'one of 1, 2, 4 or 8'…"""
    if spec.choices:
        shown = [repr(c) if isinstance(c, str) else _number(c) for c in spec.choices]
        return "one of " + (", ".join(shown[:-1]) + " or " + shown[-1] if len(shown) > 1 else shown[0])
    if spec.kind is bool:
        return "true or false"
    if spec.kind is str:
        return "a string"
    what = {int: "an integer", tuple: "a list of numbers each"}.get(spec.kind, "a number")
    noun = what.split()[-1]
    if spec.kind is float and spec.low == 0 and spec.high is None:
        text = f"a positive {noun}" if spec.low_open else f"a finite non-negative {noun}"
    elif spec.low is not None and spec.high is not None:
        text = f"{what} in {_bounds(spec)}"
    elif _bounds(spec):
        text = f"{what} {_bounds(spec)}"
    else:
        text = f"a finite {noun}" if spec.kind is float else what
    return text + (", or null (off)" if spec.optional else "")


def short_range(spec: Spec) -> str:
    """The range in a few characters, for cfg/params.yaml: '[0, 0.2]', '≥ 0', 'integer ≥ 1', '1 | 2 | 4 | 8'…"""
    if spec.choices:
        return " | ".join(str(c) for c in spec.choices)
    if spec.kind is bool:
        return "true | false"
    if spec.kind is str:
        return "text"
    prefix = {int: "integer ", tuple: "each "}.get(spec.kind, "")
    return prefix + (_bounds(spec) or "any") + (" or null" if spec.optional else "")


def expected_type(spec: Spec, default) -> str:
    """The type a value must have, for people ('true or false', 'an integer', 'a number', 'a list of numbers')."""
    if spec.kind is bool:
        return "true or false"
    if spec.kind is int:
        return "an integer"
    if spec.kind is float:
        return "a number" + (" or null" if spec.optional else "")
    if spec.kind is tuple:
        return f"a list of numbers such as {list(default)}"
    return describe_range(spec) if spec.choices else "a string"


def coerce(value, spec: Spec, default):
    """``value`` (from YAML or a ROS parameter) as the parameter's type (an int is a fine float; a list a fine
    tuple; a boolean whose word is a choice, that word), or raise ValueError saying what was expected."""
    if value is None and spec.optional:
        return None
    kind = spec.kind
    if kind is str and isinstance(value, bool) and str(value).lower() in spec.choices:
        value = str(value).lower()  # roslaunch and YAML read the word true (a choice: ~north) as a boolean
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        value = float(value) if ok else value
    elif kind is tuple:
        ok = isinstance(value, (list, tuple)) and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                      for x in value)
        value = tuple(float(x) for x in value) if ok else value
    else:
        ok = isinstance(value, kind)
    if not ok:
        raise ValueError(f"expected {expected_type(spec, default)}, got {value!r}")
    return value


def _in_range(x, spec: Spec) -> bool:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        return False
    if spec.kind is int and not isinstance(x, int):
        return False
    lo_ok = spec.low is None or (x > spec.low if spec.low_open else x >= spec.low)
    hi_ok = spec.high is None or (x < spec.high if spec.high_open else x <= spec.high)
    return lo_ok and hi_ok


def _valid(value, spec: Spec) -> bool:
    if value is None:
        return spec.optional
    if spec.choices:
        return value in spec.choices and type(value) is type(spec.choices[0])
    if spec.kind is bool:
        return isinstance(value, bool)
    if spec.kind is str:
        return isinstance(value, str)
    if spec.kind is tuple:
        return isinstance(value, tuple) and len(value) > 0 and all(_in_range(x, spec._replace(kind=float))
                                                                     for x in value)
    return _in_range(value, spec)


def problem(value, spec: Spec) -> str:
    """'' when ``value`` is within ``spec``, else ``expected <range>, got <value>``."""
    return "" if _valid(value, spec) else f"expected {describe_range(spec)}, got {value!r}"


class Params:
    """Base of every params dataclass: each field declared with :func:`param`, all checked when the object is
    made (and by :func:`dataclasses.replace`). ``error``: the class raised, naming the field."""

    error: ClassVar[Type[AbsOrientError]] = ConfigurationError

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise ``error`` naming the first field out of its range (then the rules across fields)."""
        for f in dataclasses.fields(self):
            wrong = problem(getattr(self, f.name), f.metadata["spec"])
            if wrong:
                raise self.error(f"{self.label(f.name)}: {wrong}")
        self.check_together()

    def check_together(self) -> None:
        """The class's rules that involve several fields (none by default); raise ``error``."""

    @classmethod
    def label(cls, name: str) -> str:
        """How an error names the field ``name``."""
        return f"{cls.__name__}.{name}"
