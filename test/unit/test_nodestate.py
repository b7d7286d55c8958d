"""nodestate: the node's map→odom stamp policy, its prediction and its health report, with hand-checked
numbers and the real map→odom filter (no ROS)."""
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aruco_abs_orient.correction import MapOdomFilter
from aruco_abs_orient.errors import ConfigurationError
from aruco_abs_orient.nodestate import (
    IMAGE_JUMPED_BACK,
    IMAGE_NOT_AFTER,
    IMAGE_OK,
    MapOdomPrediction,
    MapOdomStamps,
    NodeHealth,
    NodeSnapshot,
)
from aruco_abs_orient.transforms import make_T, rot_z, yaw_of


def test_an_estimate_is_future_dated_by_the_tolerance():
    p = MapOdomStamps(tolerance=0.1, period=0.05, jump_tolerance=0.5)
    assert p.for_estimate(10.0) == pytest.approx(10.1)
    assert p.for_estimate(10.033) == pytest.approx(10.133)
    assert p.last_sent == pytest.approx(10.133)
    assert MapOdomStamps(0.0, 0.05, 0.5).for_estimate(10.0) == 10.0   # tolerance 0: stamped at the image time


def test_republication_follows_the_odometry_one_period_at_a_time():
    p = MapOdomStamps(tolerance=0.1, period=0.05, jump_tolerance=0.5)
    assert p.republish(5.0) == pytest.approx(5.1)     # nothing sent yet: due at once
    assert p.republish(5.03) is None                  # 5.13 < 5.1 + 0.05
    assert p.republish(5.05) == pytest.approx(5.15)   # a period later
    assert p.republish(5.05) is None                  # the same stamp is never sent twice
    assert p.republish(4.9) is None                   # nor an older one


def test_an_image_half_a_second_late_corrects_at_the_next_newer_stamp():
    """Images 0.5 s late: the odometry (and so the re-published stamps) is ahead of every image time."""
    p = MapOdomStamps(tolerance=0.1, period=0.05, jump_tolerance=0.5)
    assert p.for_estimate(10.0) == pytest.approx(10.1)
    assert p.republish(10.6) == pytest.approx(10.7)
    assert p.for_estimate(10.1) is None               # 10.2 would go back behind 10.7: held back
    assert p.held_back == 1 and p.pending
    assert p.republish(10.6) is None                  # 10.7 again: not after the newest sent
    assert p.republish(10.62) == pytest.approx(10.72)  # pending: due although less than a period on
    assert not p.pending
    assert p.republish(10.65) is None                 # back to one period: 10.75 < 10.72 + 0.05
    assert p.republish(10.67) == pytest.approx(10.77)


def test_image_stamps_jumping_back_or_repeating():
    p = MapOdomStamps(tolerance=0.1, period=0.05, jump_tolerance=0.5)
    assert p.check_image(100.0) == IMAGE_OK
    assert p.check_image(100.0) == IMAGE_NOT_AFTER    # repeated
    assert p.check_image(99.6) == IMAGE_NOT_AFTER     # 0.4 s back: within the tolerance, skipped
    assert p.last_image == 100.0
    assert p.check_image(99.4) == IMAGE_JUMPED_BACK   # 0.6 s back: a clock jump
    p.for_estimate(100.0)
    p.reset()
    assert p.last_image is None and p.last_sent is None
    assert p.check_image(99.4) == IMAGE_OK            # the new timeline
    assert p.for_estimate(99.4) == pytest.approx(99.5)
    assert p.jumped_back(100.0, 99.4) and not p.jumped_back(100.0, 99.6) and not p.jumped_back(None, 0.0)


@pytest.mark.parametrize("args,message", [((-0.1, 0.05, 0.5), "transform tolerance"),
                                          ((0.1, 0.0, 0.5), "re-publication period"),
                                          ((0.1, 0.05, math.nan), "time jump tolerance")])
def test_bad_settings_are_refused(args, message):
    with pytest.raises(ConfigurationError, match=message):
        MapOdomStamps(*args)


@given(st.lists(st.tuples(st.sampled_from(["image", "odom"]), st.floats(0.0, 20.0)), max_size=60),
       st.floats(0.0, 0.3), st.floats(0.01, 0.2))
def test_the_stamps_sent_only_go_forward(calls, tolerance, period):
    """Whatever the order of image and odometry times (late images, a replay at rate 4): a stamp is sent at
    most once, each is after every one sent before (never an older map->odom for a time already
    covered), and each is the estimate's own time plus the tolerance."""
    p = MapOdomStamps(tolerance, period, jump_tolerance=0.5)
    sent = []
    for kind, t in calls:
        stamp = p.for_estimate(t) if kind == "image" else p.republish(t)
        if stamp is not None:
            assert stamp == t + tolerance
            assert not sent or stamp > sent[-1]
            sent.append(stamp)
    assert len(sent) + p.held_back <= len(calls)


def test_replay_at_rate_4_keeps_the_consumer_covered():
    """A replay at 4x: odometry at 30 Hz; the node takes 50 ms wall (0.2 s of sim time) per image, so it
    processes every 6th frame, 0.2 s after its capture, and re-publishes between images. After each
    loop the newest stamp sent covers the newest odometry by the tolerance, so a consumer's lookup at
    the odometry's time never extrapolates."""
    p = MapOdomStamps(tolerance=0.1, period=0.05, jump_tolerance=0.5)
    sent = []
    for k in range(1, 50):                    # the node is free again at sim time 0.2 k = frame 6 k
        image_t = 6 * (k - 1) / 30            # the image it processed was captured 0.2 s before
        odom_t = 6 * k / 30                   # newest odometry in the tf buffer
        for stamp in (p.for_estimate(image_t), p.republish(odom_t)):
            if stamp is not None:
                assert not sent or stamp > sent[-1]
                sent.append(stamp)
        assert p.last_sent >= odom_t + 0.1 - 1e-9
    assert p.held_back == 48  # each image after the first: its 0.2 s old stamp is the one re-published before


# ----------------------------------------------------------------------------------------------- health
def _report(h, now_wall, **kw):
    args = {"initialised": True, "image_age_wall": 0.1, "last_prism_stamp": 99.8, "prisms_waiting": False,
            "images_received": 0, "images_dropped": 0, "time_offset": 0.0, "time_offset_source": "parameter"}
    args.update(kw)
    return h.report(now_wall, 100.0, NodeSnapshot(**args))


def test_health_rates_and_levels_since_the_previous_report():
    h = NodeHealth(image_timeout=2.0, prism_timeout=1.0, publish_tf=True, start_wall=0.0)
    h.count("processed", 30)
    h.set_seen([7, 3, 7])
    h.latencies_ms.extend([10.0, 20.0, 30.0, 40.0])
    h.add_stages({"track": 60.0})
    h.add_stages({"track": 30.0})
    level, message, values = _report(h, 2.0, images_received=40, images_dropped=10)
    assert (level, message) == ("warn", "cannot keep up: 10 of 40 images dropped (the oldest), processing 15.0 Hz")
    assert values["rate [Hz]"] == pytest.approx(15.0)            # 30 processed in 2 s
    assert values["marker ids"] == "3 7" and values["markers seen"] == 2
    assert values["dropped fraction"] == pytest.approx(0.25)
    assert values["latency median [ms]"] == pytest.approx(25.0)
    assert values["latency p95 [ms]"] == pytest.approx(38.5)     # 30 + 0.85 * 10
    assert values["prism age [s]"] == pytest.approx(0.2)
    assert values["stage track [ms]"] == pytest.approx(3.0)      # 90 ms over 30 frames
    h.error("tf_failures", "tf odom -> base_link: no data")
    h.error("tf_failures", "tf odom -> base_link: no data")
    level, message, values = _report(h, 3.0, images_received=40, images_dropped=10)  # none dropped since
    assert (level, message) == ("warn", "2 tf lookups failed")
    assert values["rate [Hz]"] == 0.0 and values["tf failures"] == 2 and "stage track [ms]" not in values
    assert values["last error"] == "tf odom -> base_link: no data"
    h.count("processed", 27)
    level, message, _ = _report(h, 4.0, images_received=70, images_dropped=10)   # nothing new: recovered
    assert (level, message) == ("ok", "tracking 2 marker(s)")
    h.count("processed", 20)
    level, message, _ = _report(h, 5.0, images_received=100, images_dropped=20)  # 10 more dropped
    assert (level, message) == ("warn", "cannot keep up: 10 of 30 images dropped (the oldest), processing 20.0 Hz")


def test_health_waiting_stale_inputs_and_an_extra_key():
    h = NodeHealth(image_timeout=2.0, prism_timeout=1.0, publish_tf=False, start_wall=0.0,
                   frames=("base_link", "cam", "prism"))
    level, message, values = _report(h, 1.0, initialised=False, last_prism_stamp=None)
    assert (level, message) == ("warn", "no prism yet")
    level, message, _ = _report(h, 2.0, initialised=False)
    assert (level, message) == ("warn", "initialising: waiting for the static tfs")
    h.error("no_static_tf", "waiting for the static tf base_link -> cam")
    level, message, _ = _report(h, 3.0, initialised=False, image_age_wall=2.5, last_prism_stamp=97.0)
    assert level == "error"
    assert message == "no static tf base_link -> cam/prism; no image for 2.5 s; no prism for 3.0 s"
    h.extra_values["tilt source"] = lambda: "imu"
    _, _, values = _report(h, 4.0)
    assert values["tilt source"] == "imu" and values["publish_tf"] is False


# ------------------------------------------------------------------------------------------------ prediction
def test_prediction_by_hand():
    A = make_T(rot_z(3.1), [1.0, 2.0, 0.5])
    B = make_T(rot_z(-3.1), [1.2, 2.0, 0.5])            # 2π − 6.2 = 0.0832 rad later: across ±π, wrapped
    p = MapOdomPrediction(10.0, A, 12.0, B)
    half = p.at(11.0)
    assert float(yaw_of(half[:3, :3])) == pytest.approx(3.1 + (2 * math.pi - 6.2) / 2)
    np.testing.assert_allclose(half[:3, 3], [1.1, 2.0, 0.5])
    np.testing.assert_allclose(p.at(14.0)[:3, 3], [1.4, 2.0, 0.5])   # extrapolated
    with pytest.raises(ConfigurationError, match="t1"):
        MapOdomPrediction(1.0, A, 1.0, B)
    v = MapOdomPrediction(10.0, A, 12.0, B, (1e-6, 3e-6))   # the yaw's variance grows linearly from t0
    assert v.yaw_variance(11.0) == pytest.approx(2e-6) and v.yaw_variance(9.0) == pytest.approx(1e-6)
    assert math.isnan(p.yaw_variance(11.0))


def test_prediction_reproduces_the_filters_own():
    """Two predictions of the real map->odom filter (a state with a yaw drift rate) give all its others."""
    f = MapOdomFilter(np.array([-0.05, 0.0, 0.7]))
    snap = {"t": 100.0, "x": [0.4, 3.0, -2.0, 0.1, math.radians(0.1) / 60], "P": (np.eye(5) * 1e-4).tolist(),
            "odom_pos": [1.0, 1.0, 0.0], "noise_scale": 1.0}
    assert f.restore(snap, 100.5, max_age=10.0) == ""
    p = MapOdomPrediction(100.5, f.map_T_odom(100.5)[0], 101.5, f.map_T_odom(101.5)[0])
    for t in (100.9, 102.0, 105.0):
        np.testing.assert_allclose(p.at(t), f.map_T_odom(t)[0], atol=1e-12)


def test_the_state_file_is_per_node_and_master_and_restored_only_by_its_writer():
    from aruco_abs_orient.nodestate import state_path, state_record, state_snapshot

    assert state_path("/r/.ros/abs_orient_state.json", "/abs_orient", "http://localhost:11311/") == \
        "/r/.ros/abs_orient_state.abs_orient.11311.json"
    assert state_path("/r/s.json", "/robot1/abs_orient", "http://10.0.0.2:45123") == "/r/s.robot1.abs_orient.45123.json"
    assert state_path("", "/abs_orient", "http://localhost:11311/") == ""
    me = {"node": "/abs_orient", "master": "http://localhost:11311/", "run_id": "a1"}
    snap = {"t": 1.0, "x": [0.0] * 5}
    assert state_snapshot(state_record(snap, me), me) == (snap, "")
    another_run = dict(me, run_id="b2")   # a second replay on a new roscore, same HOME
    got, why = state_snapshot(state_record(snap, another_run), me)
    assert got is None and why == "written by another run (roscore /run_id): 'b2', not 'a1'"
    got, why = state_snapshot(state_record(snap, dict(me, node="/other")), me)
    assert got is None and why.startswith("written by another node")
    assert state_snapshot(snap, me) == (None, "not a state of this version (no writer)")  # an older file
