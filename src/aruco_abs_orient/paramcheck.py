"""What the params dataclasses share: validation on construction and the range check.

In: a params dataclass instance and the error class of the module it configures. Out: :class:`Validated`
(a base whose dataclasses run their ``validate()`` when constructed) and :func:`check_non_negative`: nothing,
or that error naming the first field that is not a finite non-negative number, as ``Class.field: expected a
finite non-negative number, got …`` (cfg/params.yaml's reader prefixes the file and section).
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Type

__all__ = ["Validated", "check_non_negative"]


class Validated:
    """Base of a params dataclass that checks itself when constructed (``validate`` raises naming the field)."""

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        raise NotImplementedError


def check_non_negative(params, error: Type[Exception]) -> None:
    """Raise ``error`` naming the first field of the dataclass ``params`` that is not a finite number ≥ 0."""
    for f in fields(params):
        v = getattr(params, f.name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise error(f"{type(params).__name__}.{f.name}: expected a finite non-negative number, got {v!r}")
