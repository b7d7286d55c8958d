"""nodecontrol: the abs_orient node's decisions without ROS, on a real pipeline with hand-checked numbers.

The frames are marker observations (the pipeline's ``process_observations``; the node hands it grey images):
four markers around a base at yaw 0.3 rad, the prism holding still. Stamps are camera time = total-station
time + the time offset.
"""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from aruco_abs_orient.mapcheck import DOES_NOT_FIT, FITS, MapVerdict
from aruco_abs_orient.markers import Marker, MarkerMap
from aruco_abs_orient.nodeconfig import NodeConfig
from aruco_abs_orient.nodecontrol import NodeControl, has_marker_yaw, reconfigurable_names
from aruco_abs_orient.north import NorthReference
from aruco_abs_orient.transforms import yaw_of

from .test_pipeline import BASE_T_CAMERA, BASE_T_PRISM, MAP_T_BASE, MARKERS, ODOM_T_BASE, PRISM, YAW, observation

WRITER = {"node": "/abs_orient", "master": "http://localhost:11311/", "run_id": "run-1"}


class Log:
    """rospy's logging functions, recorded."""

    def __init__(self):
        self.lines = []

    def loginfo(self, text):
        self.lines.append(("info", text))

    def logwarn(self, text):
        self.lines.append(("warn", text))

    def logerr(self, text):
        self.lines.append(("error", text))

    def logwarn_throttle(self, period, text):
        self.lines.append(("warn", text))


def control(now=10.0, writer=WRITER, **params):
    """A NodeControl on the test world's map; ``params``: the node's ``~`` parameters."""
    values = {"~markers": "markers.yaml", "~estimate_time_offset": False, **{"~" + k: v for k, v in params.items()}}
    config = NodeConfig.from_params(lambda name, default: values.get(name, default))
    mm = MarkerMap([Marker(i, np.array(p, dtype=float), 0.19, 0.002) for i, p in MARKERS.items()])
    resets = []
    ctl = NodeControl(config, mm, NorthReference(), Log(), lambda: now, lambda: dict(writer),
                      on_reset=lambda: resets.append(1))
    ctl.resets = resets
    return ctl


def static_tf(child):
    return {"camera": BASE_T_CAMERA, "prism": BASE_T_PRISM}[child]


def frames_through(ctl, camera_stamps, sent=None):
    """Each stamp: take the image, feed the prisms, process the four markers, send map→odom (into ``sent``)."""
    ctl.pipeline.process_image = lambda t, obs, odom: ctl.pipeline.process_observations(t, obs, odom)
    results = []
    for s in camera_stamps:
        assert ctl.take_image(s)
        ctl.feed_prisms()
        result = ctl.process_frame(s, [observation(i) for i in MARKERS], ODOM_T_BASE)
        if result.map_T_odom is not None and sent is not None:
            ctl.send_estimate(result, s, lambda stamp, T: sent.append((stamp, T)))
        results.append(result)
    return results


def started(offset=0.25, **params):
    """A control with its pipeline and the prism still at PRISM from 0 to 3 s (total-station time)."""
    ctl = control(time_offset=offset, **params)
    assert ctl.ensure_pipeline(static_tf)
    for t in np.arange(0.0, 3.01, 0.1):
        ctl.prism_in(float(t), PRISM, None)
    return ctl


def test_the_pipeline_waits_for_the_static_tfs_and_says_which():
    ctl = control()

    def missing(child):
        raise LookupError('"prism" passed to lookupTransform argument source_frame does not exist')

    assert not ctl.ensure_pipeline(missing) and ctl.pipeline is None
    assert ctl.health.counts["no_static_tf"] == 1
    assert ctl.health.last_error.startswith("waiting for the static tf base_link -> camera: ")
    level, message, _ = ctl.pipeline_status(0.0, 0, 0)
    assert (level, message) == ("error", "no static tf base_link -> camera/prism; no prism yet")
    assert ctl.ensure_pipeline(static_tf) and ctl.pipeline is not None and ctl.mapcheck is not None
    assert ("info", "abs_orient: lever arms from tf: camera at [0.  0.  0.5] m, prism at [0. 0. 1.] m in "
                    "base_link") in ctl.log.lines
    assert np.allclose(ctl.selfcheck.prism_lever, [0.0, 0.0, 1.0])   # started again with the lever arm


def test_frames_are_processed_in_total_station_time_and_map_odom_goes_out_future_dated():
    ctl, sent = started(offset=0.25), []
    results = frames_through(ctl, [1.25, 1.35, 1.45], sent)
    assert [r.stamp for r in results] == pytest.approx([1.0, 1.1, 1.2])   # camera stamp − 0.25 s
    assert ctl.initialised and ctl.last_result is results[-1] and ctl.health.counts["processed"] == 3
    assert has_marker_yaw(results[-1]) and results[-1].fused_yaw == pytest.approx(YAW, abs=1e-9)
    # the filter starts on the third frame: its map→odom sent at its image stamp + ~transform_tolerance (0.1 s)
    assert [stamp for stamp, _ in sent] == pytest.approx([1.55])
    assert np.allclose(sent[0][1] @ ODOM_T_BASE, MAP_T_BASE, atol=1e-6)
    assert ctl.health.counts["tf_published"] == 1
    # the timer's prediction at the newest odometry stamp, due a period (1/20 s) after 1.55 s: 1.48 s + 0.1 s
    # is too early, 1.51 s + 0.1 s is due; the prediction is taken in total-station time (1.51 − 0.25 s)
    prediction, offset = ctl.republish(1.48, lambda *a: sent.append(a))
    assert offset == 0.25 and len(sent) == 1
    assert ctl.republish(1.51, lambda *a: sent.append(a))[0] is prediction
    assert sent[-1][0] == pytest.approx(1.61) and np.allclose(sent[-1][1], prediction.at(1.51 - 0.25))
    assert ctl.health.counts["tf_republished"] == 1


def test_a_late_frame_is_held_back_and_no_tf_goes_out_when_the_ekf_owns_it():
    ctl, sent = started(offset=0.0), []
    frames_through(ctl, [1.0, 1.1, 1.2], sent)
    n = len(sent)
    assert ctl.republish(1.3, lambda *a: sent.append(a))    # sent at 1.4
    frames_through(ctl, [1.25], sent)                         # 1.35 ≤ 1.4: held back
    assert len(sent) == n + 1 and ctl.health.counts["tf_held_back"] == 1
    quiet, none = started(offset=0.0, publish_tf=False), []
    frames_through(quiet, [1.0, 1.1, 1.2], none)
    assert none == [] and quiet.health.counts["tf_published"] == 0 and quiet.initialised


def test_an_image_stamp_going_back_skips_the_frame_or_resets_the_node():
    ctl = started(offset=0.0)
    frames_through(ctl, [1.0, 1.1, 1.2])
    assert not ctl.take_image(1.2) and ctl.health.counts["out_of_order"] == 1      # the same stamp: skipped
    assert ctl.health.last_error == "image stamp 1.200 s not after the previous one, 1.200 s"
    assert not ctl.take_image(0.8)                                                   # 0.4 s back: skipped
    assert ctl.take_image(0.6) and ctl.resets == [1]                                 # 0.6 s > 0.5 s: a reset
    assert ctl.health.counts["resets"] == 1 and not ctl.initialised and ctl.prediction is None
    assert ctl.last_prism_stamp is None and ctl.stamps.last_image == 0.6
    assert ("warn", "abs_orient: image time jumped back by 0.600 s: resetting (filter, tracking, prism history, "
                    "tf buffer)") in ctl.log.lines


def test_a_prism_stamp_going_back_resets_the_node():
    ctl = started(offset=0.0)
    ctl.feed_prisms()
    assert ctl.last_prism_stamp == pytest.approx(3.0) and ctl.health.counts["prisms"] == 31
    ctl.prism_in(2.4, PRISM, None)     # 0.6 s back
    ctl.feed_prisms()
    assert ctl.health.counts["resets"] == 1 and ctl.resets == [1] and ctl.last_prism_stamp == 2.4
    ctl.prism_errors.append("frame_id 'odom', expected 'map'")
    ctl.feed_prisms()
    assert ctl.health.last_error == "ms60/prism: frame_id 'odom', expected 'map'"


def test_a_map_that_does_not_fit_stops_map_odom_for_good():
    ctl, sent = started(offset=0.0), []
    frames_through(ctl, [1.0, 1.1, 1.2], sent)
    assert ctl.prediction is not None
    n = len(sent)
    ctl.take_map_verdict(MapVerdict(DOES_NOT_FIT, "the marker map is rotated by +90.0° about z", {"markers": [0, 1]}))
    assert ctl.map_refused and ctl.prediction is None
    assert ctl.republish(2.0, lambda *a: sent.append(a)) is None
    frames_through(ctl, [1.3], sent)
    assert len(sent) == n                                      # estimated, not sent
    ctl.take_map_verdict(MapVerdict(FITS, "fits", {}))         # a later window does not take it back
    assert ctl.map_verdict.status == DOES_NOT_FIT
    assert [line for line in ctl.log.lines if line[0] == "error"] == [
        ("error", "abs_orient: the marker map is rotated by +90.0° about z: map->odom, the absolute yaw and pose are "
                  "no longer published (check ~markers markers.yaml)")]
    level, message, _ = ctl.pipeline_status(1.0, 4, 0)
    assert (level, message) == ("error", "the marker map is rotated by +90.0° about z; map->odom not published")
    assert ctl.mapcheck_status() == ("error", "the marker map is rotated by +90.0° about z", {"markers": "[0, 1]"})


def test_the_map_check_runs_every_2_s_until_the_map_fits_then_every_15_s():
    ctl = started(offset=0.0)
    worker = ctl.check_map(100.0)
    assert worker is not None and ctl.check_map(100.5) is None   # one at a time
    worker.join()
    assert ctl.map_verdict.status != DOES_NOT_FIT                # too few sightings: not checked yet
    assert ctl.check_map(101.9) is None
    ctl.check_map(102.0).join()
    ctl.map_verdict = MapVerdict(FITS, "fits", {})
    assert ctl.check_map(116.9) is None and ctl.check_map(117.0) is not None


def test_the_state_file_is_restored_by_the_node_and_run_that_wrote_it(tmp_path):
    path = str(tmp_path / "state.json")
    ctl = started(offset=0.0, state_file=path)
    frames_through(ctl, [1.0, 1.1, 1.2])
    ctl.save_state(50.0)
    assert ctl.state_file == str(tmp_path / "state.abs_orient.11311.json")
    record = json.loads(Path(ctl.state_file).read_text())
    assert record["writer"] == WRITER and record["filter"]["t"] == pytest.approx(1.2)
    again = control(now=3.2, state_file=path)                  # 2 s later (≤ ~state_max_age 10 s)
    assert again.ensure_pipeline(static_tf)
    assert again.initialised and again.prediction is not None
    assert float(yaw_of(again.prediction.at(3.2)[:3, :3] @ ODOM_T_BASE[:3, :3])) == pytest.approx(YAW, abs=1e-6)
    assert again.log.lines[-1] == ("info", f"abs_orient: started from the map->odom state in {ctl.state_file} "
                                           "(2.00 s old)")
    other = control(now=3.2, state_file=path, writer=dict(WRITER, run_id="run-2"))
    assert other.ensure_pipeline(static_tf) and not other.initialised and other.prediction is None
    assert other.log.lines[-1] == ("info", f"abs_orient: not starting from {ctl.state_file}: written by another run "
                                           "(roscore /run_id): 'run-1', not 'run-2'")


def test_reconfigured_values_wait_for_the_pipeline_and_a_bad_one_is_counted():
    ctl = control(time_offset=0.0)
    everything = {"time_offset": 0.0, "min_range": 0.5, "groups": {}}
    ctl.reconfigured(everything)                               # the server's first call: its current values
    ctl.apply_params()
    ctl.reconfigured(dict(everything, time_offset=0.3, min_range=3.2))
    ctl.apply_params()
    assert (ctl.time_offset, ctl.time_offset_source) == (0.3, "parameter")
    assert ctl.selfcheck.time_offset == 0.3                    # the self-checks start afresh on it
    assert ctl.ensure_pipeline(static_tf) and ctl.pipeline.params.min_range == 3.2
    ctl.reconfigured(dict(everything, time_offset=0.3, min_range=-1.0))
    ctl.apply_params()
    assert ctl.health.counts["bad_params"] == 1 and ctl.pipeline.params.min_range == 3.2
    assert "min_range" in reconfigurable_names() and "time_offset" in reconfigurable_names()


def test_a_failing_pipeline_is_counted_and_its_traceback_logged_once():
    ctl = started(offset=0.0)

    def fail(t, image, odom):
        raise RuntimeError("boom")

    ctl.pipeline.process_image = fail
    for s in (1.0, 1.1):
        assert ctl.take_image(s) and ctl.process_frame(s, None, ODOM_T_BASE) is None
    assert ctl.health.counts["pipeline_exceptions"] == 2 and ctl.health.counts["processed"] == 0
    assert ctl.health.last_error == "pipeline failed on the image at 1.100 s: RuntimeError: boom"
    tracebacks = [text for level, text in ctl.log.lines if level == "error"]
    assert len(tracebacks) == 1 and "RuntimeError: boom" in tracebacks[0]


def test_the_self_checks_are_fed_and_evaluated_at_most_every_5_s():
    ctl = started(offset=0.0)
    results = frames_through(ctl, [1.0, 1.1, 1.2])
    for s, r in zip((1.0, 1.1, 1.2), results):
        ctl.after_frame(s, r, ODOM_T_BASE)
    first = ctl.selfcheck_status(100.0)
    ctl.selfcheck = None                                       # not asked again within 5 s
    assert ctl.selfcheck_status(104.9) is first
    level, message, values = ctl.selfcheck_status(105.0)       # asked, and failing: a note, not an exception
    assert level == "ok" and values["self-check note"].startswith("AttributeError")


def test_the_pipeline_status_reports_the_node_state():
    ctl = started(offset=0.25)
    frames_through(ctl, [1.25, 1.35, 1.45])
    level, message, values = ctl.pipeline_status(ctl.last_image_wall + 0.5, 3, 1)
    assert values["initialised"] is True and values["time offset [s]"] == 0.25
    assert values["map->odom yaw [deg]"] == pytest.approx(math.degrees(float(yaw_of(
        (MAP_T_BASE @ np.linalg.inv(ODOM_T_BASE))[:3, :3]))), abs=1e-4)
    assert values["images dropped"] == 1 and message.startswith(
        "no prism for 7.0 s; cannot keep up: 1 of 3 images dropped (the oldest), processing ")
    assert ctl.tilt_source() == (ctl.last_result.tilt_source or "-")
    ctl.health.count("imu_unusable", 2)
    assert ctl.tilt_source().endswith(" (2 IMU samples unusable)")



class Estimator:
    """The live estimator's interface (OnlineOffsetEstimator), suggesting ``better`` s; records what it is fed."""

    def __init__(self, better):
        self.better, self.applied, self.applied_sigma, self.fed = better, better, 0.004, []

    def add_vo(self, s, yaw):
        self.fed.append(("vo", s))

    def add_marker_yaw(self, s, yaw):
        self.fed.append(("marker", s))

    def update_in_background(self, s):
        pass

    def suggestion(self, in_use):
        return self.better


def test_a_confident_live_time_offset_replaces_the_one_in_use_unless_the_marker_yaws_veto_it():
    ctl = started(offset=0.25)
    results = frames_through(ctl, [1.25, 1.35, 1.45])
    ctl.offset_estimator = est = Estimator(0.37)
    ctl.selfcheck.last_time_offset = {"suggested_s": 0.25, "sigma_s": 0.001}   # the marker yaws: 0.25 s
    ctl.after_frame(1.45, results[-1], ODOM_T_BASE)
    assert est.fed == [("vo", 1.45), ("marker", 1.45)]                         # camera clock
    assert ctl.time_offset == 0.25 and ctl.health.counts["time_offset_switch_refused"] == 1
    ctl.selfcheck.last_time_offset = None                                      # no check yet: no veto
    ctl.after_frame(1.45, results[-1], ODOM_T_BASE)
    assert (ctl.time_offset, ctl.time_offset_source) == (0.37, "live estimate")
    assert ctl.selfcheck.time_offset == 0.37 and ctl.selfcheck.last_time_offset is None   # started afresh
    assert ctl.log.lines[-1] == ("warn", "abs_orient: time offset 0.2500 s -> 0.3700 s (live estimate ± 4.0 ms "
                                         "contradicts the one in use)")
