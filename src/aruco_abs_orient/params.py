"""cfg/params.yaml: every pipeline tunable in one file, generated from the params dataclasses and read back.

In: the params dataclasses of the modules they configure (:data:`SECTIONS`: the pipeline's
:data:`aruco_abs_orient.pipeline.PARAM_GROUPS`, ``PipelineParams`` in pipeline.py, ``DetectorParams`` in
detection/params.py, ``TrackingParams`` in tracking.py, ``FilterParams`` in correction.py, and the time-offset
estimate's ``TimeSyncParams`` in timesync/coherence.py, the report's ``EvaluationParams`` in evaluation.py and
``calibrate``'s ``CalibrationParams`` in calibration/model.py and ``map``'s ``MappingParams`` in
mapping/model.py; their defaults are written there, once) and, to
read, a YAML file with any subset of them under the group's section::

    tracking:
      gate_deg: 1.5
    filter:
      gate_chi2_yaw: 12.0

Out: :func:`defaults_yaml` (the documented defaults: what cfg/params.yaml holds, written by
``aruco-abs-orient params``), :func:`load_params` (the file → :class:`Tunables`, one object per group,
defaults where the file is silent) and :class:`ParamsError`: one line naming the file, the key and what
was expected (unknown section or name, wrong type, value out of range).
"""

from __future__ import annotations

import difflib
import inspect
import math
import re
import textwrap
from dataclasses import fields, replace
from typing import Dict, NamedTuple, Optional

import yaml

from .calibration import CalibrationParams
from .correction import FilterParams
from .detection import DetectorParams
from .errors import AbsOrientError, ConfigurationError
from .evaluation import EvaluationParams
from .mapping import MappingParams
from .pipeline import PARAM_GROUPS, PipelineParams
from .timesync import TimeSyncParams
from .tracking import TrackingParams
from .tum import read_yaml

__all__ = ["SECTIONS", "ParamsError", "Tunables", "load_params", "parse_params", "defaults_yaml", "describe"]


#: (section, params class) of every section of cfg/params.yaml, in its order: the pipeline's groups (what
#: ``AbsOrientPipeline`` and dynamic_reconfigure take), then the time-offset estimate's (``timesync``, the
#: node's ``~estimate_time_offset``), the report's (``evaluation``), calibrate's (``calibration``) and map's
#: (``mapping``)
SECTIONS = PARAM_GROUPS + (("timesync", TimeSyncParams), ("evaluation", EvaluationParams),
                           ("calibration", CalibrationParams), ("mapping", MappingParams))


class ParamsError(ConfigurationError):
    """A params file with an unknown section or name, a wrong type or a value out of range (one line)."""


class Tunables(NamedTuple):
    """One params object per group (``AbsOrientPipeline(..., **tunables.pipeline_kwargs())``)."""

    pipeline: PipelineParams
    detection: DetectorParams
    tracking: TrackingParams
    filter: FilterParams
    timesync: TimeSyncParams
    evaluation: EvaluationParams
    calibration: CalibrationParams
    mapping: MappingParams

    def pipeline_kwargs(self) -> dict:
        """Keyword arguments of :class:`~aruco_abs_orient.pipeline.AbsOrientPipeline`."""
        return {"params": self.pipeline, "detector_params": self.detection, "tracking_params": self.tracking,
                "filter_params": self.filter}

    def flat(self) -> Dict[str, object]:
        """name → value of every tunable the node reads (names are unique across those sections:
        dynamic_reconfigure's view); calibrate's and map's own sections are not among them."""
        return {f.name: getattr(obj, f.name) for obj in self if not isinstance(obj, (CalibrationParams, MappingParams))
                for f in fields(obj)}


def _expected(default) -> str:
    if isinstance(default, bool):
        return "true or false"
    if isinstance(default, int):
        return "an integer"
    if isinstance(default, float):
        return "a number"
    if isinstance(default, tuple):
        return f"a list of numbers such as {list(default)}"
    return f"one of the strings this field takes (default {default!r})" if isinstance(default, str) else "a value"


def _coerce(value, default, where: str):
    """``value`` as the type of ``default`` (an int is a fine float), else ParamsError naming ``where``."""
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        value = float(value) if ok else value
    elif isinstance(default, tuple):
        ok = isinstance(value, (list, tuple)) and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                      for x in value)
        value = tuple(float(x) for x in value) if ok else value
    else:
        ok = isinstance(value, type(default))
    if not ok:
        raise ParamsError(f"{where}: expected {_expected(default)}, got {value!r}")
    return value


def parse_params(data, source: str = "<params>") -> Tunables:
    """:class:`Tunables` from a parsed YAML mapping ``{section: {name: value}}`` (``source`` names it in errors)."""
    groups = dict(SECTIONS)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ParamsError(f"{source}: expected a mapping of sections ({', '.join(groups)}), "
                          f"got {type(data).__name__}")
    out = {}
    for section, cls in SECTIONS:
        given = data.get(section) or {}
        if not isinstance(given, dict):
            raise ParamsError(f"{source}: {section}: expected a mapping of parameter names to values, "
                              f"got {type(given).__name__}")
        defaults = cls()
        known = {f.name: getattr(defaults, f.name) for f in fields(cls)}
        changes = {}
        for name, value in given.items():
            where = f"{source}: {section}.{name}"
            if name not in known:
                elsewhere = [s for s, c in SECTIONS if name in {f.name for f in fields(c)}]
                hint = (f"it belongs in section {elsewhere[0]!r}" if elsewhere else
                        "did you mean " + " or ".join(repr(m) for m in difflib.get_close_matches(str(name), known, 2))
                        if difflib.get_close_matches(str(name), known, 2) else
                        f"expected a parameter of {cls.__name__} (see cfg/params.yaml)")
                raise ParamsError(f"{where}: unknown parameter; {hint}")
            changes[name] = _coerce(value, known[name], where)
        try:
            obj = replace(defaults, **changes)
            if hasattr(obj, "validate"):
                obj.validate()
        except AbsOrientError as e:  # the class's own range checks name the field
            raise ParamsError(f"{source}: {section}: {e}") from None
        out[section] = obj
    unknown = sorted(set(data) - set(groups))
    if unknown:
        raise ParamsError(f"{source}: unknown section {unknown[0]!r}; expected one of {', '.join(groups)}")
    return Tunables(**out)


def load_params(path: Optional[str]) -> Tunables:
    """The tunables of a params YAML file (None or '': every default). Raises ParamsError (one line)."""
    if not path:
        return parse_params({})
    return parse_params(read_yaml(path, ParamsError), path)


# --------------------------------------------------------------------------- the documented defaults

def _bullets(doc: str) -> Dict[str, str]:
    """name → text of the ``- ``name``: text`` bullets of a params docstring; a bullet naming several
    fields (``a``, ``b``: text; ``x_min/max``) describes each of them."""
    out: Dict[str, str] = {}
    items, cur = [], None
    for line in inspect.cleandoc(doc).splitlines():
        stripped = line.strip()
        if stripped.startswith("- "):
            cur = [stripped[2:]]
            items.append(cur)
        elif cur is not None and stripped and line.startswith("  "):
            cur.append(stripped)
        else:
            cur = None
    texts = [" ".join(item) for item in items]
    for text in texts:  # the fields a bullet is about: named before its colon
        for name in re.findall(r"``([\w/]+)``", text.partition(": ")[0]):
            parts = name.split("/")  # ``adaptive_thresh_win_min/max/step``
            prefix = parts[0].rsplit("_", 1)[0]
            for n in [parts[0]] + [f"{prefix}_{p}" for p in parts[1:]]:
                out.setdefault(n, text)
    for text in texts:  # fields named only inside another field's bullet
        for name in re.findall(r"``(\w+)``", text):
            out.setdefault(name, text)
    return out


def _inline_comments(cls) -> Dict[str, str]:
    """name → the ``# comment`` after a field's definition in the class source."""
    out = {}
    for line in inspect.getsource(cls).splitlines():
        m = re.match(r"\s+(\w+): [^=]+=.*?#\s*(.+)$", line)
        if m:
            out[m.group(1)] = m.group(2).strip()
    return out


def describe(cls) -> Dict[str, str]:
    """name → description of every field of a params class (its docstring bullet or its inline comment)."""
    docs = _bullets(cls.__doc__ or "")
    docs.update({k: v for k, v in _inline_comments(cls).items() if k not in docs})
    return {f.name: docs.get(f.name, "") for f in fields(cls)}


def _yaml_value(v) -> str:
    text = yaml.safe_dump(v, default_flow_style=True).strip()
    return text[:-4].strip() if text.endswith("...") else text


def defaults_yaml() -> str:
    """The text of cfg/params.yaml: every tunable with its default and description, by section."""
    lines = ["# Every tunable with its default (generated from the params dataclasses by",
             "# `aruco-abs-orient params --out cfg/params.yaml`; test/unit/test_params.py checks it is current).",
             "# Give a copy with your changes (any subset) to `aruco-abs-orient process|calibrate|timesync|evaluate",
             "# --params FILE` or to the node as ~params. Who reads what: pipeline, detection, tracking and filter:",
             "# process and the node (calibrate and timesync --markers: detection); timesync: timesync and the",
             "# node's ~estimate_time_offset; evaluation: evaluate. Units are in the names (*_deg, *_px) or the",
             "# descriptions; angles without _deg are radians, times seconds, lengths metres."]
    for section, cls in SECTIONS:
        module = "src/" + cls.__module__.replace(".", "/") + ".py"
        lines += ["", f"{section}:  # {cls.__name__}, {module}"]
        desc = describe(cls)
        defaults = cls()
        previous = None
        for f in fields(cls):
            text = re.sub(r":\w+:`~?\.?([^`]+)`", r"\1", desc[f.name]).replace("``", "")  # plain text
            if text != previous:  # a description of several fields: once, above the first
                lines += [f"  # {line}" for line in textwrap.wrap(text, 100)]
            previous = text
            lines.append(f"  {f.name}: {_yaml_value(getattr(defaults, f.name))}")
    return "\n".join(lines) + "\n"

