"""params.py and cfg/params.yaml: the committed file is what the generator writes from the params
dataclasses, it documents every tunable and reads back as the defaults; a file with a wrong name, type
or value gives one line naming the file, the key and what was expected (the CLI's --params, the node's
~params); a subset changes those tunables only."""
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest

from aruco_abs_orient.calibration import CalibrationParams
from aruco_abs_orient.correction import FilterParams
from aruco_abs_orient.detection import DetectorParams
from aruco_abs_orient.evaluation import EvaluationParams
from aruco_abs_orient.mapping import MappingParams
from aruco_abs_orient.markers import MarkerMap
from aruco_abs_orient.offline.cli import main as cli_main
from aruco_abs_orient.params import SECTIONS, ParamsError, defaults_yaml, describe, load_params, parse_params
from aruco_abs_orient.pipeline import PARAM_GROUPS, AbsOrientPipeline, PipelineParams, all_param_fields
from aruco_abs_orient.timesync import TimeSyncParams
from aruco_abs_orient.tracking import TrackingParams

ROOT = Path(__file__).resolve().parents[2]
COMMITTED = ROOT / "cfg" / "params.yaml"


def test_the_committed_file_is_what_the_generator_writes():
    assert COMMITTED.read_text(encoding="utf-8") == defaults_yaml(), (
        "cfg/params.yaml is stale: run `aruco-abs-orient params --out cfg/params.yaml`")


def test_every_tunable_is_in_the_file_with_a_description_and_reads_back_as_its_default():
    t = load_params(str(COMMITTED))
    assert tuple(t) == (PipelineParams(), DetectorParams(), TrackingParams(), FilterParams(), TimeSyncParams(),
                        EvaluationParams(), CalibrationParams(), MappingParams())
    assert tuple(section for section, _ in SECTIONS) == t._fields and SECTIONS[:len(PARAM_GROUPS)] == PARAM_GROUPS
    text = COMMITTED.read_text(encoding="utf-8")
    for section, cls in SECTIONS:
        assert f"\n{section}:" in text
        for name, desc in describe(cls).items():
            assert desc, f"{cls.__name__}.{name} has no description (a docstring bullet or an inline comment)"
            assert f"\n  {name}: " in text
    # unique names: dynamic_reconfigure's flat view (what the node reads: not calibrate's section, whose
    # prism_sigma/prism_max_gap are the pipeline's defaults, set apart for the solve, nor map's)
    assert len(t.flat()) == len(all_param_fields()) + len(fields(TimeSyncParams)) + len(fields(EvaluationParams))


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
    ("tracking:\n  sweep_period_frames: 0\n", r"p\.yaml: tracking: TrackingParams\.sweep_period_frames: "
                                               r"expected ≥ 1, got 0"),
    ("tracking:\n  max_full_interval: 2.5\n", r"tracking\.max_full_interval: expected an integer, got 2\.5"),
    ("detection:\n  pole_views: 1\n", r"detection\.pole_views: expected true or false, got 1"),
    ("detection:\n  max_view_px: 10.5\n", r"detection\.max_view_px: expected an integer, got 10\.5"),
    ("detection:\n  rescue_shrink: 0.5\n", r"detection\.rescue_shrink: expected a list of numbers"),
    ("detection:\n  pole_band_deg: 95.0\n", r"p\.yaml: detection: DetectorParams\.pole_band_deg: expected \(0, 90\)"),
    ("pipeline:\n  jpeg_reduce: 3\n", r"p\.yaml: pipeline: PipelineParams\.jpeg_reduce: expected 1, 2, 4 or 8"),
    ("filters:\n  gate_chi2_yaw: 3.0\n", r"p\.yaml: unknown section 'filters'; expected one of pipeline, "
                                         r"detection, tracking, filter, timesync, evaluation"),
    ("timesync:\n  smooth: 0\n", r"p\.yaml: timesync: TimeSyncParams\.smooth: expected a positive number, got 0"),
    ("timesync:\n  window: -60\n", r"timesync: TimeSyncParams\.window: expected a finite non-negative number"),
    ("timesync:\n  smoothing: 1.0\n", r"p\.yaml: timesync\.smoothing: unknown parameter; did you mean 'smooth'"),
    ("evaluation:\n  max_gap: -1\n", r"p\.yaml: evaluation: EvaluationParams\.max_gap: expected a finite "
                                      r"non-negative number, got -1"),
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


def test_the_node_reads_params_and_names_a_bad_key():
    pytest.importorskip("rospy", reason="the node's config needs ROS's Python (rospy)")
    from aruco_abs_orient.ros.abs_orient_node import NodeConfig, NodeConfigError

    def getter(values):
        return lambda name, default: values.get(name, default)

    markers = str(ROOT / "cfg" / "markers_example.yaml")
    config = NodeConfig.from_params(getter({"~markers": markers, "~params": str(COMMITTED)}))
    assert config.tunables().detection == DetectorParams() and config.tunables().tracking == TrackingParams()
    with pytest.raises(NodeConfigError, match=r"~params: .*nowhere\.yaml: cannot read"):
        NodeConfig.from_params(getter({"~markers": markers, "~params": "/nowhere.yaml"}))


def test_params_fields_are_plain_values():
    """Every tunable is a bool, int, float, str or tuple of numbers: what YAML and the checks above handle."""
    for _, cls in SECTIONS:
        for f in fields(cls):
            assert isinstance(getattr(cls(), f.name), (bool, int, float, str, tuple)), f"{cls.__name__}.{f.name}"
