"""synthetic/bag.py + cli.py: the tiny preset written and read back with rosbags AND with Debian's
rosbag module (topics, types, md5s, counts, stamps, latched /tf_static, values vs the scenario's
truth), the truth/markers/hidden files, atomic writing, and the CLI's error paths (exit 2)."""
import dataclasses
import os

import cv2
import numpy as np
import pytest

from aruco_abs_orient.markers import MarkerMap
from aruco_abs_orient.synthetic import bag as bagmod
from aruco_abs_orient.synthetic.bag import OUTPUT_FILES, GenerateError, generate, make_typestore
from aruco_abs_orient.synthetic.cli import main
from aruco_abs_orient.synthetic.scenario import PRESETS, Scenario
from aruco_abs_orient.transforms import make_T, quat_to_matrix
from aruco_abs_orient.tum import read_tum

CFG = PRESETS["tiny"]


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny")
    result = generate(CFG, str(out), progress=False)
    return out, result, Scenario(CFG)


def _sec(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def _matrix(tr) -> np.ndarray:
    q, p = tr.rotation, tr.translation
    return make_T(quat_to_matrix([q.x, q.y, q.z, q.w]), [p.x, p.y, p.z])


def test_outputs_and_no_leftovers(generated):
    out, result, sc = generated
    assert sorted(os.listdir(out)) == sorted(OUTPUT_FILES)  # no temporary files left
    assert result.frames == sc.frame_times.size == int(CFG.duration * CFG.fps)
    assert os.path.getsize(result.bag) < 10e6  # JPEG 85 of a smooth background stays small


def test_read_with_rosbags(generated):
    from rosbags.rosbag1 import Reader

    out, result, sc = generated
    store = make_typestore()
    with Reader(result.bag) as reader:
        conns = {c.topic: c for c in reader.connections}
        assert {t: c.msgtype for t, c in conns.items()} == bagmod.TOPICS
        assert conns["/tf_static"].ext.latching == 1
        assert conns["/tf"].ext.latching in (0, None)
        counts = {t: c.msgcount for t, c in conns.items()}
        assert counts == {"/camera/image/compressed": result.frames, "/tf": result.frames, "/tf_static": 1,
                          "/ms60/prism": sc.prism.stamps.size}
        images, tfs, prism, static, record_times = [], [], [], [], []
        for conn, t_ns, raw in reader.messages():
            msg = store.deserialize_ros1(raw, conn.msgtype)
            record_times.append(t_ns)
            if conn.topic == "/camera/image/compressed":
                images.append(msg)
                assert t_ns == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            elif conn.topic == "/tf":
                tfs.append(msg)
            elif conn.topic == "/ms60/prism":
                prism.append(msg)
            else:
                static.append(msg)
    assert record_times == sorted(record_times)  # written in time order
    # images: camera clock stamps, frame "camera", JPEG of the right size
    stamps = np.array([_sec(m.header.stamp) for m in images])
    np.testing.assert_allclose(stamps, sc.camera_stamps, atol=2e-6)
    assert all(m.format == "jpeg" and m.header.frame_id == "camera" for m in images)
    img = cv2.imdecode(np.asarray(images[0].data), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (CFG.width // 2, CFG.width)
    # odom → base_link at the camera stamps equals the drift model at true time = stamp − offset
    assert all(len(m.transforms) == 1 for m in tfs)
    trs = [m.transforms[0] for m in tfs]
    assert {(tr.header.frame_id, tr.child_frame_id) for tr in trs} == {("odom", "base_link")}
    tf_stamps = np.array([_sec(tr.header.stamp) for tr in trs])
    np.testing.assert_allclose(tf_stamps, stamps, atol=1e-9)
    got = np.array([_matrix(tr.transform) for tr in trs])
    np.testing.assert_allclose(got, sc.odom_T_base(tf_stamps - CFG.camera_time_offset), atol=1e-5)
    # prism: true-time stamps, frame map, the scenario's samples
    assert all(m.header.frame_id == "map" for m in prism)
    np.testing.assert_allclose([_sec(m.header.stamp) for m in prism], sc.prism.stamps, atol=2e-6)
    np.testing.assert_allclose([[m.point.x, m.point.y, m.point.z] for m in prism], sc.prism.positions, atol=1e-12)
    # static: the NOMINAL camera rotation (the boresight error is not published) and the prism arm
    edges = {(tr.header.frame_id, tr.child_frame_id): _matrix(tr.transform) for tr in static[0].transforms}
    np.testing.assert_allclose(edges[("base_link", "camera")], sc.base_T_camera_nominal, atol=1e-12)
    np.testing.assert_allclose(edges[("base_link", "prism")], sc.base_T_prism, atol=1e-12)
    assert not np.allclose(edges[("base_link", "camera")], sc.base_T_camera_true, atol=1e-4)


def test_read_with_debian_rosbag(generated):
    rosbag = pytest.importorskip("rosbag", reason="Debian's python3-rosbag")
    out, result, sc = generated
    with rosbag.Bag(result.bag) as b:
        info = b.get_type_and_topic_info()
        assert info.msg_types == {"sensor_msgs/CompressedImage": "8f7a12909da2c9d3332d540a0977563f",
                                  "tf2_msgs/TFMessage": "94810edda583a504dfda3829e70d7eec",
                                  "geometry_msgs/PointStamped": "c63aecb41bfdfd6b7e1fac37c7cbe7bf"}
        assert {t: v.message_count for t, v in info.topics.items()} == {
            "/camera/image/compressed": result.frames, "/tf": result.frames, "/tf_static": 1,
            "/ms60/prism": sc.prism.stamps.size}
        latched = {c.topic: c.header.get("latching") for c in b._get_connections()}
        assert latched["/tf_static"] in (b"1", "1")
        odom = []
        for _topic, msg, t in b.read_messages(topics=["/tf"]):
            tr = msg.transforms[0]
            assert tr.header.stamp == t
            odom.append((tr.header.stamp.to_sec(), _matrix(tr.transform)))
        for _topic, msg, _t in b.read_messages(topics=["/camera/image/compressed"]):
            assert msg.format == "jpeg" and len(msg.data) > 1000
            break
        assert b.get_start_time() <= sc.prism.stamps[0] + 1e-6
    s = np.array([o[0] for o in odom])
    np.testing.assert_allclose(np.array([o[1] for o in odom]), sc.odom_T_base(s - CFG.camera_time_offset),
                               atol=1e-5)


def test_truth_markers_hidden(generated):
    out, result, sc = generated
    truth = read_tum(result.truth)
    np.testing.assert_allclose(truth.stamps, sc.frame_times, atol=1e-6)  # TRUE times
    np.testing.assert_allclose(truth.transforms, sc.map_T_base(truth.stamps), atol=1e-5)
    markers = MarkerMap.load(result.markers)
    assert markers.ids == sc.markers.ids
    np.testing.assert_allclose(markers.positions(), sc.markers.positions(), atol=1e-6)
    assert markers.dictionary == CFG.dictionary
    back = Scenario.from_hidden(result.hidden)
    assert back.config == CFG
    np.testing.assert_array_equal(back.odom_T_base(sc.frame_times), sc.odom_T_base(sc.frame_times))


def _image_messages(path):
    from rosbags.rosbag1 import Reader

    with Reader(path) as reader:
        conns = [c for c in reader.connections if c.topic == "/camera/image/compressed"]
        return [raw for _c, _t, raw in reader.messages(connections=conns)]


def test_parallel_rendering_is_ordered_and_deterministic(tmp_path):
    short = dataclasses.replace(CFG, duration=1.0)  # 10 frames: ≥ 8 uses the process pool
    one = generate(short, str(tmp_path / "one"), progress=False, workers=1)
    two = generate(short, str(tmp_path / "two"), progress=False, workers=2)
    assert _image_messages(one.bag) == _image_messages(two.bag)


def test_failed_render_leaves_no_bag(tmp_path, monkeypatch):
    calls = []

    def failing(index):  # fault injection: the 4th frame fails
        calls.append(index)
        if index == 3:
            raise RuntimeError("render failed")
        return real(index)

    real = bagmod._render_frame
    monkeypatch.setattr(bagmod, "_render_frame", failing)
    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="render failed"):
        generate(dataclasses.replace(CFG, duration=1.0), str(out), progress=False, workers=1)
    assert calls[-1] == 3
    assert os.listdir(out) == []


def test_existing_outputs_need_force(generated, tmp_path):
    out, _result, _sc = generated
    with pytest.raises(GenerateError, match="--force"):
        generate(CFG, str(out), progress=False)


def test_cli_writes_a_scenario(tmp_path, capsys):
    out = tmp_path / "cli"
    rc = main(["--preset", "tiny", "--duration", "0.5", "--seed", "3", "--time-offset", "0.25",
               "--boresight-deg", "0.5", "--out", str(out), "--quiet"])
    assert rc == 0
    assert sorted(os.listdir(out)) == sorted(OUTPUT_FILES)
    sc = Scenario.from_hidden(str(out / "hidden.yaml"))
    assert (sc.config.seed, sc.config.duration, sc.config.camera_time_offset, sc.config.boresight_deg) == (
        3, 0.5, 0.25, 0.5)
    assert str(out) in capsys.readouterr().out


@pytest.mark.parametrize("argv,match", [
    (["--width", "abc"], "--width"),
    (["--width", "961"], "width"),
    (["--fps", "0"], "--fps"),
    (["--seed", "-1"], "--seed"),
    (["--preset", "huge"], "--preset"),
    (["--duration"], "--duration"),
    (["--boresight-deg", "45"], "boresight_deg"),
])
def test_cli_bad_arguments_exit_2_with_one_line(argv, match, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        rc = main(["--preset", "tiny", "--out", str(tmp_path / "o"), "--quiet"] + argv)
        raise SystemExit(rc)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and match in err and "Traceback" not in err
    assert not (tmp_path / "o" / "scenario.bag").exists()


def test_cli_unwritable_or_existing_output_exit_2(generated, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert main(["--preset", "tiny", "--out", str(blocker / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot create" in err
    out, _result, _sc = generated
    assert main(["--preset", "tiny", "--out", str(out), "--quiet"]) == 2
    assert "--force" in capsys.readouterr().err
