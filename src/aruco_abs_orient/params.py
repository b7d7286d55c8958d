"""cfg/params.yaml: every tunable in one file, generated from the params dataclasses and read back.

In: the params classes (:data:`SECTIONS`), each field declared once with its default, meaning, unit and range
(:func:`aruco_abs_orient.paramspec.param`), and, to read, a mapping of any subset of them by section: a YAML
file (the offline tools' ``--params``) or the node's private parameters (``~filter/gate_chi2_yaw``, loaded by
``<rosparam file=...>``)::

    tracking:
      gate_deg: 1.5
    filter:
      gate_chi2_yaw: 12.0

Out: :func:`defaults_yaml` (what cfg/params.yaml holds, written by ``aruco-abs-orient params``),
:func:`load_params` / :func:`parse_params` (→ :class:`Tunables`, one object per section, defaults where the
input is silent) and :class:`ParamsError`: one line naming the file (or ``~section/name``), the key and what
was expected (unknown section or name, wrong type, value out of range).
"""

from __future__ import annotations

import difflib
import textwrap
from dataclasses import fields, replace
from typing import Dict, NamedTuple, Optional

import yaml

from .calibration import CalibrationParams
from .correction import FilterParams
from .detection import DetectorParams
from .errors import AbsOrientError, ConfigurationError
from .evaluation import EvaluationParams
from .mapcheck import MapCheckParams
from .mapping import MappingParams
from .paramspec import coerce, problem, short_range, specs
from .pipeline import PARAM_GROUPS, PipelineParams
from .selfcheck import SelfCheckParams
from .solver import FitSettings
from .tilt import TiltParams
from .timesync import TimeSyncParams
from .tracking import TrackingParams
from .tum import read_yaml

__all__ = ["SECTIONS", "ParamsError", "Tunables", "load_params", "parse_params", "defaults_yaml", "comment"]


#: (section, params class) of every section of cfg/params.yaml, in its order: the pipeline's groups (what
#: ``AbsOrientPipeline`` and dynamic_reconfigure take), the pipeline's fixed ones (tilt, the multi-marker fits),
#: the self-checks' and the map check's (process and the node), the time-offset estimate's (``timesync``, the
#: node's ``~estimate_time_offset``), the report's (``evaluation``), calibrate's (``calibration``) and map's
#: (``mapping``)
SECTIONS = PARAM_GROUPS + (("tilt", TiltParams), ("fit", FitSettings), ("selfcheck", SelfCheckParams),
                           ("mapcheck", MapCheckParams), ("timesync", TimeSyncParams),
                           ("evaluation", EvaluationParams), ("calibration", CalibrationParams),
                           ("mapping", MappingParams))

#: who reads which section (cfg/params.yaml's header)
READERS = ("pipeline, detection, tracking, filter, tilt and fit: process and the node (calibrate and timesync "
           "--markers: detection); selfcheck and mapcheck: process and the node (calibrate: mapcheck); timesync: "
           "timesync and the node's ~estimate_time_offset; evaluation: evaluate; calibration: calibrate and "
           "process's self-checks (not the node: its ~calibration is the calibration file); mapping: map")


class ParamsError(ConfigurationError):
    """A params file or the node's parameters with an unknown section or name, a wrong type or a value out of
    range (one line)."""


class Tunables(NamedTuple):
    """One params object per section (``AbsOrientPipeline(..., **tunables.pipeline_kwargs())``)."""

    pipeline: PipelineParams
    detection: DetectorParams
    tracking: TrackingParams
    filter: FilterParams
    tilt: TiltParams
    fit: FitSettings
    selfcheck: SelfCheckParams
    mapcheck: MapCheckParams
    timesync: TimeSyncParams
    evaluation: EvaluationParams
    calibration: CalibrationParams
    mapping: MappingParams

    def pipeline_kwargs(self) -> dict:
        """Keyword arguments of :class:`~aruco_abs_orient.pipeline.AbsOrientPipeline`."""
        return {"params": self.pipeline, "detector_params": self.detection, "tracking_params": self.tracking,
                "filter_params": self.filter, "tilt_params": self.tilt, "fit_settings": self.fit}

    def flat(self) -> Dict[str, object]:
        """name → value of every tunable of the pipeline's groups (:data:`PARAM_GROUPS`; their names are unique:
        dynamic_reconfigure's view)."""
        return {f.name: getattr(getattr(self, section), f.name) for section, cls in PARAM_GROUPS
                for f in fields(cls)}


def _unknown(section: str, name: str, cls) -> str:
    """Why ``name`` is not a parameter of ``section``: where it belongs, or what was meant."""
    elsewhere = [s for s, c in SECTIONS if name in {f.name for f in fields(c)}]
    if elsewhere:
        return f"it belongs in section {elsewhere[0]!r}"
    close = difflib.get_close_matches(str(name), [f.name for f in fields(cls)], 2)
    if close:
        return "did you mean " + " or ".join(repr(m) for m in close)
    return f"expected a parameter of {cls.__name__} (see cfg/params.yaml)"


def _section(cls, given: dict, where) -> object:
    """The params object of one section: its defaults with ``given`` (name → value) checked and applied;
    ``where(name)`` names a key in errors."""
    defaults, spec = cls(), specs(cls)
    changes = {}
    for name, value in given.items():
        if name not in spec:
            raise ParamsError(f"{where(name)}: unknown parameter; {_unknown(where.section, name, cls)}")
        try:
            value = coerce(value, spec[name], getattr(defaults, name))
        except ValueError as e:
            raise ParamsError(f"{where(name)}: {e}") from None
        wrong = problem(value, spec[name])
        if wrong:
            raise ParamsError(f"{where(name)}: {wrong}")
        changes[name] = value
    try:
        return replace(defaults, **changes)
    except AbsOrientError as e:  # a rule across fields
        raise ParamsError(f"{where('')}{e}") from None


class _Where:
    """How errors name a key: ``file: section.name`` (a YAML file) or ``~section/name`` (the node's parameters)."""

    def __init__(self, source: str, section: str, ros: bool):
        self.source, self.section, self.ros = source, section, ros

    def __call__(self, name: str) -> str:
        if self.ros:
            return f"~{self.section}/{name}" if name else f"~{self.section}: "
        return f"{self.source}: {self.section}.{name}" if name else f"{self.source}: {self.section}: "


def parse_params(data, source: str = "<params>", ros: bool = False) -> Tunables:
    """:class:`Tunables` from a mapping ``{section: {name: value}}`` (parsed YAML, or the node's private
    parameters with ``ros``: errors then name ``~section/name``); ``source`` names it in errors."""
    groups = dict(SECTIONS)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ParamsError(f"{source}: expected a mapping of sections ({', '.join(groups)}), "
                          f"got {type(data).__name__}")
    out = {}
    for section, cls in SECTIONS:
        where = _Where(source, section, ros)
        given = data.get(section) or {}
        if not isinstance(given, dict):
            raise ParamsError(f"{where('')}expected a mapping of parameter names to values, "
                              f"got {type(given).__name__}")
        out[section] = _section(cls, given, where)
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

def _yaml_value(v) -> str:
    text = yaml.safe_dump(v, default_flow_style=True).strip()
    return text[:-4].strip() if text.endswith("...") else text


def comment(spec) -> str:
    """A parameter's line of documentation: its meaning, then its unit and range in brackets."""
    return f"{spec.meaning} [{spec.unit + ', ' if spec.unit else ''}{short_range(spec)}]"


def defaults_yaml() -> str:
    """The text of cfg/params.yaml: every tunable with its default and description, by section."""
    lines = ["# Every tunable with its default, meaning, unit and range (generated from the params dataclasses by",
             "# `aruco-abs-orient params --out cfg/params.yaml`; test/unit/test_params.py checks it is current).",
             "# Give a copy with your changes (any subset) to `aruco-abs-orient process|calibrate|timesync|evaluate",
             "# --params FILE`, or load it into the node's namespace (abs_orient.launch params:=FILE, or",
             "# <rosparam command=\"load\" file=\"FILE\"/> first inside its <node>: ~filter/gate_chi2_yaw).",
             "# Who reads what:"]
    lines += [f"# {line}" for line in textwrap.wrap(READERS + ".", 110)]
    lines += ["# Units: rad, s, m unless the bracket or the name (*_deg, *_px) says otherwise."]
    for section, cls in SECTIONS:
        module = "src/" + cls.__module__.replace(".", "/") + ".py"
        lines += ["", f"{section}:  # {cls.__name__}, {module}"]
        defaults = cls()
        for name, spec in specs(cls).items():
            lines += [f"  # {line}" for line in textwrap.wrap(comment(spec), 108)]
            lines.append(f"  {name}: {_yaml_value(getattr(defaults, name))}")
    return "\n".join(lines) + "\n"
