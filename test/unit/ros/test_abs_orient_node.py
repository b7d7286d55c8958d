"""The abs_orient node's ROS-free parts: its parameters, its one-slot mailbox, and cfg/AbsOrient.cfg run
through dynamic_reconfigure's real generator and checked against the pipeline's tunables.

(The node itself runs in the rostests test/abs_orient_*.test.) Needs tools/env.sh sourced, as `make test`.
"""
import math
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from aruco_abs_orient.pipeline import all_param_fields
from aruco_abs_orient.ros.abs_orient_node import Mailbox, NodeConfig, NodeConfigError, reconfigurable_names

ROOT = Path(__file__).resolve().parents[3]


def _getter(values):
    return lambda name, default: values.get(name, default)


def test_node_config_defaults_and_values():
    c = NodeConfig.from_params(_getter({"~markers": "/m.yaml", "~time_offset": 1, "~publish_tf": False}))
    assert c.markers == "/m.yaml" and c.time_offset == 1.0 and isinstance(c.time_offset, float)
    assert c.publish_tf is False and c.image_transport == "compressed" and c.map_frame == "map"


@pytest.mark.parametrize("values,message", [
    ({}, "~markers: no marker map given"),
    ({"~markers": "m", "~image_transport": "theora"}, "~image_transport: expected 'compressed' or 'raw'"),
    ({"~markers": "m", "~tf_rate": 0.0}, "~tf_rate: expected a positive number"),
    ({"~markers": "m", "~time_offset": "0.3"}, "~time_offset: expected a number, got '0.3'"),
    ({"~markers": "m", "~time_offset": float("nan")}, "~time_offset: expected a number"),
    ({"~markers": "m", "~publish_tf": "false"}, "~publish_tf: expected true or false"),
    ({"~markers": 3}, "~markers: expected a string"),
    ({"~markers": "m", "~north": "magnetic"}, "~north: expected 'grid' or 'true'"),
])
def test_node_config_errors_name_the_parameter(values, message):
    with pytest.raises(NodeConfigError, match=message.replace("(", r"\(")):
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


def test_cfg_covers_every_pipeline_knob(generated_cfg):
    """The pipeline's own knobs (PipelineParams) are all reconfigurable but the camera's (read when the pipeline is
    made); detection/filter ones selectively."""
    from aruco_abs_orient.pipeline import CAMERA_FIELDS

    pipeline_names = {name for group, name, _ in all_param_fields() if group == "pipeline"} - set(CAMERA_FIELDS)
    assert pipeline_names <= set(generated_cfg.defaults)
