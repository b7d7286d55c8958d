"""The abs_orient node's ROS-free parts: its parameters, its one-slot mailbox, and cfg/AbsOrient.cfg run
through dynamic_reconfigure's real generator and checked against the parameters' declarations.

(The node itself runs in the rostests test/abs_orient_*.test.) Needs tools/env.sh sourced, as `make test`.
"""
import ast
import math
import re
import threading
import time
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
import yaml

from aruco_abs_orient.nodeconfig import NODE_SECTIONS, NodeConfig, NodeConfigError
from aruco_abs_orient.params import parse_params
from aruco_abs_orient.paramspec import spec_of
from aruco_abs_orient.pipeline import PARAM_GROUPS, PipelineParams, all_param_fields
from aruco_abs_orient.ros.abs_orient_node import Mailbox, reconfigurable_names

ROOT = Path(__file__).resolve().parents[3]


def _getter(values):
    return lambda name, default: values.get(name, default)


def test_node_config_defaults_and_values():
    c = NodeConfig.from_params(_getter({"~markers": "/m.yaml", "~time_offset": 1, "~publish_tf": False}))
    assert c.markers == "/m.yaml" and c.time_offset == 1.0 and isinstance(c.time_offset, float)
    assert c.publish_tf is False and c.image_transport == "compressed" and c.map_frame == "map"


@pytest.mark.parametrize("values,message", [
    ({}, "~markers: no marker map given"),
    ({"~markers": "m", "~image_transport": "theora"}, "~image_transport: expected one of 'compressed' or 'raw'"),
    ({"~markers": "m", "~tf_rate": 0.0}, "~tf_rate: expected a positive number"),
    ({"~markers": "m", "~time_offset": "0.3"}, "~time_offset: expected a number, got '0.3'"),
    ({"~markers": "m", "~time_offset": float("nan")}, "~time_offset: expected a number"),
    ({"~markers": "m", "~publish_tf": "false"}, "~publish_tf: expected true or false"),
    ({"~markers": 3}, "~markers: expected a string"),
    ({"~markers": "m", "~north": "magnetic"}, "~north: expected one of 'grid' or 'true'"),
    ({"~markers": "m", "~time_offset": 7.0}, "~time_offset: expected a number in [-5, 5], got 7.0"),
    ({"~markers": "m", "~rate_tolerance": 1.0}, "~rate_tolerance: expected a number in [0, 1), got 1.0"),
    ({"~markers": "m", "~filter": {"gate_chi2_yaw": -1.0}}, "~filter/gate_chi2_yaw: expected a number in [0.01, "
                                                            "1000]"),
    ({"~markers": "m", "~tracking": {"gate_dg": 1.0}}, "~tracking/gate_dg: unknown parameter; did you mean "
                                                       "'gate_deg'"),
])
def test_node_config_errors_name_the_parameter(values, message):
    with pytest.raises(NodeConfigError, match=re.escape(message)):
        NodeConfig.from_params(_getter(values))


def test_calibration_file_replaces_the_tf_lever_arms_or_stops_the_node(tmp_path):
    good = tmp_path / "calibration.yaml"
    good.write_text("base_link_to_camera: {xyz: [0.1, 0.0, 0.8], rpy_deg: [0.3, 0.0, 90.0]}\n"
                    "base_link_to_prism: {xyz: [-0.25, 0.05, 1.1]}\n")
    arms = NodeConfig.from_params(_getter({"~markers": "m", "~calibration": str(good)})).calibrated_lever_arms()
    np.testing.assert_allclose(arms["camera"][:3, 3], [0.1, 0.0, 0.8])
    R = arms["camera"][:3, :3]  # Rz(90°)·Rx(0.3°): x → y, z → (sin 0.3°, 0, cos 0.3°)
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(R @ [0.0, 0.0, 1.0], [math.sin(math.radians(0.3)), 0.0, math.cos(math.radians(0.3))],
                               atol=1e-12)
    np.testing.assert_allclose(arms["prism"][:3, 3], [-0.25, 0.05, 1.1])
    assert NodeConfig.from_params(_getter({"~markers": "m"})).calibrated_lever_arms() is None
    bad = tmp_path / "bad.yaml"
    bad.write_text("base_link_to_camera: {xyz: [0.1, 0.0]}\n")
    with pytest.raises(NodeConfigError, match=r"~calibration: .*bad.yaml: base_link_to_camera"):
        NodeConfig.from_params(_getter({"~markers": "m", "~calibration": str(bad)}))


def test_mailbox_keeps_the_newest_and_counts_what_it_replaced():
    box = Mailbox()
    assert box.take(timeout=0.01) is None
    taken = []
    stop = threading.Event()

    def worker():  # a slow consumer: 5 ms per item
        while not stop.is_set():
            item = box.take(timeout=0.05)
            if item is not None:
                taken.append(item)
                time.sleep(0.005)

    t = threading.Thread(target=worker)
    t.start()
    for i in range(300):  # a fast producer: ~ every 0.5 ms
        box.put(i)
        time.sleep(0.0005)
    time.sleep(0.05)
    stop.set()
    t.join()
    assert box.received == 300
    assert taken[-1] == 299                      # the newest always gets through
    assert taken == sorted(taken)                # never an older one after a newer one
    assert len(taken) + box.dropped == 300       # every item is taken or counted as dropped
    assert box.dropped > 100                     # the producer was ~10x faster


def test_decoder_between_two_mailboxes_drops_the_oldest_message_and_never_queues():
    """The node's hand-over: callback → messages → decoder (waits until its frame was taken) → frames →
    processing. A slow consumer sees the newest images in order; the decoder never replaces an untaken
    frame (no decoding wasted), so every drop is an older message replaced before it was decoded."""
    messages, frames = Mailbox(), Mailbox()
    taken, stop = [], threading.Event()

    def decoder():
        while not stop.is_set():
            if frames.wait_taken(timeout=0.05):
                item = messages.take(timeout=0.05)
                if item is not None:
                    time.sleep(0.002)  # decoding
                    frames.put(item)

    def consumer():  # 8 ms per frame
        while not stop.is_set():
            item = frames.take(timeout=0.05)
            if item is not None:
                taken.append(item)
                time.sleep(0.008)

    threads = [threading.Thread(target=f) for f in (decoder, consumer)]
    for t in threads:
        t.start()
    for i in range(300):  # ~ every 0.5 ms: ~16x faster than the consumer
        messages.put(i)
        time.sleep(0.0005)
    time.sleep(0.1)
    stop.set()
    for t in threads:
        t.join()
    assert taken[-1] == 299 and taken == sorted(taken)
    assert frames.dropped == 0
    assert len(taken) + messages.dropped == 300 and messages.dropped > 200
    assert frames.wait_taken(timeout=0.01)     # empty: returns at once


def test_cfg_entries_are_pipeline_tunables_with_their_defaults(generated_cfg):
    tunables = {name: default for _, name, default in all_param_fields()}
    names = set(generated_cfg.defaults)
    assert "time_offset" in names
    unknown = names - set(reconfigurable_names())
    assert not unknown, f"cfg/AbsOrient.cfg exposes names the pipeline does not know: {sorted(unknown)}"
    for name in sorted(names - {"time_offset"}):
        default, cfg_type = tunables[name], generated_cfg.type[name]
        cfg_default = generated_cfg.defaults[name]
        expected_type = {bool: "bool", int: "int", float: "double"}[type(default)]
        assert cfg_type == expected_type, f"{name}: cfg type {cfg_type}, pipeline default {default!r}"
        assert math.isclose(cfg_default, default, rel_tol=1e-12), f"{name}: cfg default {cfg_default} != {default}"
        if cfg_type != "bool":
            assert generated_cfg.min[name] <= cfg_default <= generated_cfg.max[name], name


def test_the_node_reads_the_sections_as_namespaces():
    """cfg/params.yaml's sections are the node's ~section namespaces (<rosparam file=...> loads them there)."""
    c = NodeConfig.from_params(_getter({"~markers": "m", "~tracking": {"gate_deg": 2}, "~filter": {
        "require_standstill": True}, "~calibration": ""}))
    t = c.tunables()
    assert t.tracking.gate_deg == 2.0 and t.filter.require_standstill is True and t.pipeline == PipelineParams()
    assert NodeConfig.from_params(_getter({"~markers": "m"})).tunables() == t._replace(
        tracking=type(t.tracking)(), filter=type(t.filter)())


def test_a_params_file_loaded_into_the_namespace_reaches_the_node(tmp_path):
    """What abs_orient.launch params:=FILE does: <rosparam command="load"> puts each section at ~section, then
    the node's own <param>s (~calibration, the calibration file, wins over calibrate's section of that name)."""
    data = yaml.safe_load((ROOT / "cfg" / "params.yaml").read_text(encoding="utf-8"))
    data["filter"]["gate_chi2_yaw"] = 12.0
    data["tilt"]["gate_chi2"] = 9.21
    data["mapcheck"]["live_max_sightings"] = 500
    server = {"~" + section: values for section, values in data.items()}
    server.update({"~markers": "m", "~calibration": ""})
    t = NodeConfig.from_params(_getter(server)).tunables()
    assert (t.filter.gate_chi2_yaw, t.tilt.gate_chi2, t.mapcheck.live_max_sightings) == (12.0, 9.21, 500)
    assert t._replace(filter=parse_params({}).filter, tilt=parse_params({}).tilt,
                      mapcheck=parse_params({}).mapcheck) == parse_params({})
    assert "calibration" not in NODE_SECTIONS and "timesync" in NODE_SECTIONS


@pytest.mark.parametrize("section, values, message", [
    ("filter", {"gate_chi2_yaw": 2000.0}, "~filter/gate_chi2_yaw: expected a number in [0.01, 1000], got 2000.0"),
    ("pipeline", {"jpeg_reduce": 3}, "~pipeline/jpeg_reduce: expected one of 1, 2, 4 or 8, got 3"),
    ("tilt", {"gate_chi2": 0}, "~tilt/gate_chi2: expected a positive number, got 0.0"),
    ("fit", {"loss": "l1"}, "~fit/loss: expected one of 'cauchy', 'huber' or 'none', got 'l1'"),
    ("selfcheck", {"min_samples": 2.5}, "~selfcheck/min_samples: expected an integer, got 2.5"),
    ("mapcheck", {"fit_deg": "one"}, "~mapcheck/fit_deg: expected a number, got 'one'"),
    ("pipeline", {"gate_deg": 1.0}, "~pipeline/gate_deg: unknown parameter; it belongs in section 'tracking'"),
    ("detection", 3, "~detection: expected a mapping of parameter names to values, got int"),
    ("detection", {"adaptive_thresh_win_min": 25}, "~detection: DetectorParams.adaptive_thresh_win_min/max: need"),
])
def test_a_bad_tunable_is_one_line_naming_section_and_name(section, values, message):
    with pytest.raises(NodeConfigError) as e:
        NodeConfig.from_params(_getter({"~markers": "m", "~" + section: values}))
    assert str(e.value).startswith(message) and "\n" not in str(e.value)


def _cfg_entries(generated_cfg) -> dict:
    """name → the generator's description of each entry (type, default, min, max, description, edit_method)."""
    return {p["name"]: p for g in generated_cfg.config_description["groups"] for p in g["parameters"]}


def test_cfg_ranges_and_descriptions_are_the_declarations(generated_cfg):
    """Each live entry takes its range, default and meaning from the parameter's one declaration; a parameter
    with a few allowed values is an enum of exactly those (jpeg_reduce: 1, 2, 4, 8, not 1..8)."""
    classes = dict(PARAM_GROUPS, node=NodeConfig)
    entries = _cfg_entries(generated_cfg)
    assert set(entries) == set(generated_cfg.defaults) and len(entries) > 30
    for group in generated_cfg.config_description["groups"]:
        cls = classes[group["name"]]
        for entry in group["parameters"]:
            name = entry["name"]
            spec = spec_of(cls, name)
            assert entry["description"].endswith(spec.meaning) and spec.unit in entry["description"], name
            assert entry["default"] == getattr(cls(), name), name
            if spec.choices:
                enum = ast.literal_eval(entry["edit_method"])["enum"]
                assert [c["value"] for c in enum] == list(spec.choices), name
                assert (entry["min"], entry["max"]) == (min(spec.choices), max(spec.choices)), name
            elif spec.kind is not bool:
                assert (entry["min"], entry["max"]) == (spec.low, spec.high), name
                assert not (spec.low_open or spec.high_open), name
    assert [c["value"] for c in ast.literal_eval(entries["jpeg_reduce"]["edit_method"])["enum"]] == [1, 2, 4, 8]


def test_every_parameter_is_declared_with_a_meaning_and_a_unit_and_range_where_numeric():
    """One declaration per parameter: every field of every params class (cfg/params.yaml's sections and the
    node's own) has a one-line meaning; a number has a range (or allowed values) and, unless it is a count, a
    flag or a ratio, a unit."""
    from aruco_abs_orient.params import SECTIONS

    for cls in [c for _, c in SECTIONS] + [NodeConfig]:
        for f in fields(cls):
            spec = f.metadata["spec"]
            where = f"{cls.__name__}.{f.name}"
            assert spec.meaning and "\n" not in spec.meaning and spec.meaning == spec.meaning.strip(), where
            if spec.kind in (int, float, tuple):
                assert spec.choices or spec.low is not None or spec.high is not None, where
            if spec.kind is float and not spec.choices:
                dimensionless = spec.unit == "" and any(w in spec.meaning for w in (
                    "fraction", "factor", "rate", "correlation", "lead", "ratio", "share", "step", "σ", "RMS",
                    "scale"))
                assert spec.unit or dimensionless or f.name.endswith(("_rate", "_scale")), where


def test_cfg_covers_every_pipeline_knob(generated_cfg):
    """The pipeline's own knobs (PipelineParams) are all reconfigurable but the camera's (read when the pipeline is
    made); detection/filter ones selectively."""
    from aruco_abs_orient.pipeline import CAMERA_FIELDS

    pipeline_names = {name for group, name, _ in all_param_fields() if group == "pipeline"} - set(CAMERA_FIELDS)
    assert pipeline_names <= set(generated_cfg.defaults)
