"""params.py and cfg/params.yaml: the committed file is what the generator writes from the params
dataclasses, it documents every tunable and reads back as the defaults; a file with a wrong name, type
or value gives one line naming the file, the key and what was expected (the CLI's --params; the node's
~section/name: test/unit/ros/test_abs_orient_node.py); a subset changes those tunables only."""
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest

from aruco_abs_orient.calibration import CalibrationParams
from aruco_abs_orient.correction import FilterParams
from aruco_abs_orient.detection import DetectorParams
from aruco_abs_orient.evaluation import EvaluationParams
from aruco_abs_orient.mapcheck import MapCheckParams
from aruco_abs_orient.mapping import MappingParams
from aruco_abs_orient.markers import MarkerMap
from aruco_abs_orient.offline.cli import main as cli_main
from aruco_abs_orient.params import SECTIONS, ParamsError, comment, defaults_yaml, load_params, parse_params
from aruco_abs_orient.paramspec import specs
from aruco_abs_orient.pipeline import PARAM_GROUPS, AbsOrientPipeline, PipelineParams, all_param_fields
from aruco_abs_orient.selfcheck import SelfCheckParams
from aruco_abs_orient.solver import FitSettings
from aruco_abs_orient.tilt import TiltParams
from aruco_abs_orient.timesync import TimeSyncParams
from aruco_abs_orient.tracking import TrackingParams

ROOT = Path(__file__).resolve().parents[2]
COMMITTED = ROOT / "cfg" / "params.yaml"


def test_the_committed_file_is_what_the_generator_writes():
    assert COMMITTED.read_text(encoding="utf-8") == defaults_yaml(), (
        "cfg/params.yaml is stale: run `aruco-abs-orient params --out cfg/params.yaml`")


def test_every_tunable_is_in_the_file_with_its_declaration_and_reads_back_as_its_default():
    t = load_params(str(COMMITTED))
    assert tuple(t) == (PipelineParams(), DetectorParams(), TrackingParams(), FilterParams(), TiltParams(),
                        FitSettings(), SelfCheckParams(), MapCheckParams(), TimeSyncParams(), EvaluationParams(),
                        CalibrationParams(), MappingParams())
    assert tuple(section for section, _ in SECTIONS) == t._fields and SECTIONS[:len(PARAM_GROUPS)] == PARAM_GROUPS
    text = COMMITTED.read_text(encoding="utf-8")
    for section, cls in SECTIONS:
        assert f"\n{section}:" in text
        for name, spec in specs(cls).items():
            assert f"  # {comment(spec)[:60]}" in text and f"\n  {name}: " in text, f"{cls.__name__}.{name}"
    # unique names: dynamic_reconfigure's flat view of the pipeline's groups
    assert len(t.flat()) == len(all_param_fields())


def test_a_subset_changes_only_those_and_reaches_the_pipeline(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("detection:\n  rescue_shrink: [1.0, 0.8]\ntracking:\n  gate_deg: 2\n"
                 "filter:\n  require_standstill: true\n")
    t = load_params(str(f))
    assert t.tracking.gate_deg == 2.0 and isinstance(t.tracking.gate_deg, float)  # an int is a fine float
    assert t.detection.rescue_shrink == (1.0, 0.8)
    assert t.filter.require_standstill is True
    assert t.pipeline == PipelineParams() and t.detection == replace(DetectorParams(), rescue_shrink=(1.0, 0.8))
    changed = {k for k, v in t.flat().items() if v != parse_params({}).flat()[k]}
    assert changed == {"gate_deg", "rescue_shrink", "require_standstill"}
    pipe = AbsOrientPipeline(MarkerMap([]), np.eye(4), np.eye(4), **t.pipeline_kwargs())
    assert pipe.tracker.params.gate_deg == 2.0 and pipe.filter.params.require_standstill is True
    assert pipe.tracker.detector.params.rescue_shrink == (1.0, 0.8)
    assert load_params(None) == load_params("") == parse_params({})


@pytest.mark.parametrize("text, expected", [
    ("tracking:\n  gate_dg: 1.0\n", r"p\.yaml: tracking\.gate_dg: unknown parameter; did you mean 'gate_deg'"),
    ("pipeline:\n  gate_deg: 1.0\n", r"p\.yaml: pipeline\.gate_deg: unknown parameter; it belongs in section "
                                     r"'tracking'"),
    ("detection:\n  lost_after_frames: 5\n", r"p\.yaml: detection\.lost_after_frames: unknown parameter; it "
                                              r"belongs in section 'tracking'"),
    ("tracking:\n  gate_deg: one\n", r"p\.yaml: tracking\.gate_deg: expected a number, got 'one'"),
    ("tracking:\n  sweep_period_frames: 0\n", r"p\.yaml: tracking\.sweep_period_frames: expected an integer in "
                                               r"\[1, 10000\], got 0"),
    ("tracking:\n  max_full_interval: 2.5\n", r"tracking\.max_full_interval: expected an integer, got 2\.5"),
    ("detection:\n  pole_views: 1\n", r"detection\.pole_views: expected true or false, got 1"),
    ("detection:\n  max_view_px: 10.5\n", r"detection\.max_view_px: expected an integer, got 10\.5"),
    ("detection:\n  rescue_shrink: 0.5\n", r"detection\.rescue_shrink: expected a list of numbers"),
    ("detection:\n  pole_band_deg: 95.0\n", r"p\.yaml: detection\.pole_band_deg: expected a number in \(0, 90\)"),
    ("detection:\n  rescue_shrink: [1.0, 1.5]\n", r"detection\.rescue_shrink: expected a list of numbers each in "
                                                  r"\(0, 1\], got \(1\.0, 1\.5\)"),
    ("detection:\n  adaptive_thresh_win_min: 25\n", r"p\.yaml: detection: DetectorParams\.adaptive_thresh_win_min/"
                                                   r"max: need 3 ≤ min ≤ max, got 25, 23"),
    ("pipeline:\n  jpeg_reduce: 3\n", r"p\.yaml: pipeline\.jpeg_reduce: expected one of 1, 2, 4 or 8, got 3"),
    ("filter:\n  gate_chi2_yaw: 2000\n", r"p\.yaml: filter\.gate_chi2_yaw: expected a number in \[0\.01, 1000\]"),
    ("filters:\n  gate_chi2_yaw: 3.0\n", r"p\.yaml: unknown section 'filters'; expected one of pipeline, "
                                         r"detection, tracking, filter, tilt, fit, selfcheck, mapcheck, timesync, "
                                         r"evaluation, calibration"),
    ("tilt:\n  gate_chi2: 0\n", r"p\.yaml: tilt\.gate_chi2: expected a positive number, got 0"),
    ("fit:\n  loss: l2\n", r"p\.yaml: fit\.loss: expected one of 'cauchy', 'huber' or 'none', got 'l2'"),
    ("selfcheck:\n  min_accepted_share: 1.5\n", r"selfcheck\.min_accepted_share: expected a number in \[0, 1\]"),
    ("mapcheck:\n  min_sightings: 0\n", r"mapcheck\.min_sightings: expected an integer ≥ 1, got 0"),
    ("timesync:\n  smooth: 0\n", r"p\.yaml: timesync\.smooth: expected a positive number, got 0"),
    ("timesync:\n  window: -60\n", r"timesync\.window: expected a finite non-negative number"),
    ("timesync:\n  smoothing: 1.0\n", r"p\.yaml: timesync\.smoothing: unknown parameter; did you mean 'smooth'"),
    ("evaluation:\n  max_gap: -1\n", r"p\.yaml: evaluation\.max_gap: expected a finite non-negative number, "
                                      r"got -1"),
    ("evaluation:\n  gate_deg: 1.0\n", r"p\.yaml: evaluation\.gate_deg: unknown parameter; it belongs in section "
                                       r"'tracking'"),
    ("- 1\n- 2\n", r"p\.yaml: expected a mapping of sections"),
    ("detection: 3\n", r"p\.yaml: detection: expected a mapping"),
    ("tracking:\n  gate_deg: [1\n", r"p\.yaml:\d+: not valid YAML"),
])
def test_a_wrong_name_type_or_value_is_one_line_naming_the_key(tmp_path, text, expected):
    f = tmp_path / "p.yaml"
    f.write_text(text)
    with pytest.raises(ParamsError, match=expected) as e:
        load_params(str(f))
    assert "\n" not in str(e.value)
    with pytest.raises(ParamsError, match="missing.yaml: cannot read"):
        load_params(str(tmp_path / "missing.yaml"))


def test_cli_params_writes_the_file_and_process_refuses_a_bad_one_in_one_line(tmp_path, capsys):
    out = tmp_path / "mine.yaml"
    assert cli_main(["params", "--out", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == defaults_yaml()
    bad = tmp_path / "bad.yaml"
    bad.write_text("tracking:\n  gate_deg: wide\n")
    markers = ROOT / "cfg" / "markers_example.yaml"
    code = cli_main(["process", str(tmp_path / "no.bag"), "--markers", str(markers), "--out", str(tmp_path / "o"),
                     "--params", str(bad)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1
    assert "bad.yaml: tracking.gate_deg: expected a number, got 'wide'" in err[0]


def test_an_optional_parameter_takes_null(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("fit:\n  outlier_gate: null\n")
    assert load_params(str(f)).fit == FitSettings(outlier_gate=None) != FitSettings()


def test_params_fields_are_plain_values():
    """Every tunable is a bool, int, float, str or tuple of numbers: what YAML and the checks above handle."""
    for _, cls in SECTIONS:
        for f in fields(cls):
            assert isinstance(getattr(cls(), f.name), (bool, int, float, str, tuple)), f"{cls.__name__}.{f.name}"
