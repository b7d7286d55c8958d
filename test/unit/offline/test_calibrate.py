"""offline.calibrate: the ``calibrate`` command on a rendered bag (detection → calibration → files)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import yaml

from aruco_abs_orient.calibration import load_calibration
from aruco_abs_orient.markers import MarkerMap


def _cli(argv):
    from aruco_abs_orient.offline.cli import main

    return main(["calibrate"] + [str(a) for a in argv])


def _scenario(out, **changes):
    import dataclasses

    from aruco_abs_orient.synthetic.bag import generate
    from aruco_abs_orient.synthetic.scenario import PRESETS

    config = dataclasses.replace(PRESETS["tiny"], **changes)
    generate(config, str(out), progress=False, workers=1)
    return yaml.safe_load((out / "hidden.yaml").read_text())


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """A small rendered recording (960×480, 4 fps, 12 s, 1 s standstill) with a 0.5° boresight error."""
    out = tmp_path_factory.mktemp("calib_scenario")
    hidden = _scenario(out, duration=12.0, fps=4.0, standstill=1.0, accel_time=1.0, boresight_deg=0.5,
                       n_markers=6)
    return out, hidden


@pytest.fixture(scope="module")
def calibrated(rendered, tmp_path_factory):
    """`calibrate` run once on the rendered recording, into a directory it creates: (output YAML path, what it
    printed for people, exit code)."""
    import contextlib
    import io

    out, hidden = rendered
    yaml_path = tmp_path_factory.mktemp("calibrated") / "site" / "new" / "calibration.yaml"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = _cli([out / "scenario.bag", "--markers", out / "markers.yaml", "--time-offset",
                     hidden["camera_time_offset"], "--out", yaml_path, "--quiet"])
    return yaml_path, printed.getvalue(), code


def _errors(hidden, yaml_path):
    """(roll, pitch, yaw) of the calibrated mounting against the true one (deg)."""
    from aruco_abs_orient.transforms import matrix_to_rpy

    true_T = np.array(hidden["base_T_camera_true"])
    dR = true_T[:3, :3] @ load_calibration(str(yaml_path))["camera"][:3, :3].T    # the rotation left, in base_link
    return np.degrees(matrix_to_rpy(dR))


def test_cli_recovers_the_rendered_boresight(rendered, calibrated):
    """A 0.5° error from ~50 frames of 960 px, a 12 s drive along part of the loop: each axis within 3 σ, the yaw
    within 0.1° (roll and pitch rest on the little turning there is: their σ says so; the full-size figures are in
    bench/calibration.py)."""
    _, hidden = rendered
    yaml_path, printed, code = calibrated
    assert code == 0, printed
    # a few aligned lines with units (--json gives the JSON line), the next step with the user's own paths
    before, after = (float(x) for x in re.search(r"^bearing residual RMS +([0-9.]+)° before, ([0-9.]+)° after$",
                                                  printed, re.M).groups())
    found = re.search(r"^boresight roll, pitch, yaw +(.*)$", printed, re.M).group(1)
    sigma = np.array([float(x) for x in re.findall(r"± ([0-9.]+)°", found)])
    assert re.search(r"^marker map +the marker map fits: ", printed, re.M), printed
    assert re.search(r"^platform model +the VO's ", printed, re.M), printed
    use = printed.split("use: ", 1)[1].split("   (next step)")[0]
    assert use.startswith("aruco-abs-orient process ") and f"--calibration {yaml_path}" in use, use
    err = _errors(hidden, yaml_path)
    assert np.all(np.abs(err) < 3 * sigma) and abs(err[2]) < 0.1, (err, printed)
    assert after < 0.3 * before
    np.testing.assert_allclose(load_calibration(str(yaml_path))["prism"], np.array(hidden["base_T_prism"]),
                               atol=1e-5)


def test_cli_writes_a_launch_file_roslaunch_loads(calibrated):
    """The launch file beside the calibration is one roslaunch loads (standalone or <include>d), with both
    static tfs (needs ROS's roslaunch: not on a bare Python 3.8 stack)."""
    pytest.importorskip("roslaunch", reason="needs ROS's roslaunch")
    import roslaunch.config
    import roslaunch.xmlloader

    yaml_path, _, code = calibrated
    assert code == 0
    loaded = load_calibration(str(yaml_path))
    config = roslaunch.config.ROSLaunchConfig()
    roslaunch.xmlloader.XmlLoader().load(str(yaml_path.parent / "calibration.launch"), config, verbose=False)
    tfs = {n.name: n.args.split() for n in config.nodes if n.type == "static_transform_publisher"}
    assert sorted(tfs) == ["camera_tf", "prism_tf"] and tfs["camera_tf"][-2:] == ["base_link", "camera"]
    np.testing.assert_allclose([float(x) for x in tfs["camera_tf"][:3]], loaded["camera"][:3, 3], atol=1e-6)


def test_cli_refuses_a_recording_without_motion(tmp_path, capsys):
    out = tmp_path / "still"
    out.mkdir()
    _scenario(out, duration=3.0, fps=2.0, speed=0.0, boresight_deg=0.5)
    code = _cli([out / "scenario.bag", "--markers", out / "markers.yaml", "--out", tmp_path / "c.yaml", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and "cannot calibrate" in err[0] and "drives" in err[0]
    assert not (tmp_path / "c.yaml").exists()


def test_cli_bad_input_is_one_line(rendered, tmp_path, capsys):
    out, _ = rendered
    cases = [
        ([tmp_path / "missing.bag", "--markers", out / "markers.yaml", "--out", tmp_path / "c.yaml"], "no such bag"),
        ([out / "scenario.bag", "--markers", tmp_path / "none.yaml", "--out", tmp_path / "c.yaml"], "cannot read"),
        ([out / "scenario.bag", "--markers", out / "markers.yaml", "--out", out / "scenario.bag" / "c.yaml"],
         "cannot create the directory"),
        ([out / "scenario.bag", "--markers", out / "markers.yaml", "--out", tmp_path / "c.yaml", "--every", "0"],
         "--every"),
    ]
    for argv, words in cases:
        code = _cli(argv + ["--quiet"])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and words in err[0], (argv, err)


def test_process_takes_the_readout_from_the_calibration_file(rendered, calibrated, tmp_path):
    """The calibration file's camera_readout_ms reaches process's pipeline (summary.json says which), and
    a file without one means a global shutter."""
    from aruco_abs_orient.offline.process import RunSetup, process_bag

    out, hidden = rendered
    yaml_path = calibrated[0]
    data = yaml.safe_load(yaml_path.read_text())
    markers = MarkerMap.load(str(out / "markers.yaml"))
    for readout_ms in (None, 25.0):
        if readout_ms is not None:
            data["camera_readout_ms"] = readout_ms
        path = tmp_path / f"cal_{readout_ms}.yaml"
        path.write_text(yaml.safe_dump(data))
        res_dir = tmp_path / f"out_{readout_ms}"
        process_bag(str(out / "scenario.bag"), markers, str(res_dir),
                    RunSetup(hidden["camera_time_offset"], calibration=load_calibration(str(path)), progress=False))
        summary = json.loads((res_dir / "summary.json").read_text())
        assert summary["readout_ms"] == pytest.approx(readout_ms or 0.0)


def test_cli_heading_models(rendered, tmp_path, capsys):
    """``--heading-model vo_yaw`` (the VO's yaw as the direction of travel) on the same recording: the yaw within
    0.1° and the model is the one asked for. ``vo_track`` (the VO's own track, noisier: 12 s at 0.8 m/s do not
    determine the yaw with it) is refused, the message naming the other model to try."""
    out, hidden = rendered
    yaml_path = tmp_path / "calibration.yaml"
    args = [out / "scenario.bag", "--markers", out / "markers.yaml", "--time-offset", hidden["camera_time_offset"],
            "--out", yaml_path, "--quiet", "--json", "--heading-model"]
    code = _cli(args + ["vo_yaw"])
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert json.loads(printed.splitlines()[0])["heading_model"] == "vo_yaw"
    assert abs(_errors(hidden, yaml_path)[2]) < 0.1
    yaml_path.unlink()
    assert _cli(args + ["vo_track"]) == 1
    err = capsys.readouterr().err
    assert "does not determine the boresight yaw" in err and "--heading-model vo_yaw" in err, err
    assert not yaml_path.exists()


def test_cli_params_calibration_section_reaches_the_solve(rendered, tmp_path, capsys):
    """``--params`` with a ``calibration:`` section: the solve takes its values (here more observations
    than the recording has: refused, naming the limit), and a wrong name there is one line naming it."""
    out, hidden = rendered
    args = [out / "scenario.bag", "--markers", out / "markers.yaml", "--time-offset", hidden["camera_time_offset"],
            "--out", tmp_path / "calibration.yaml", "--quiet", "--params"]
    strict = tmp_path / "strict.yaml"
    strict.write_text("calibration:\n  min_observations: 100000\n")
    assert _cli(args + [strict]) == 1
    err = capsys.readouterr().err
    assert "cannot calibrate" in err and "100000" in err, err
    assert not (tmp_path / "calibration.yaml").exists()
    bad = tmp_path / "bad.yaml"
    bad.write_text("calibration:\n  knot_spacin: 2.0\n")
    assert _cli(args + [bad]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "calibration.knot_spacin" in err[0] and "knot_spacing" in err[0], err


def test_cli_refuses_a_map_that_does_not_fit_by_name(rendered, tmp_path, capsys):
    """The recording's map shifted by 10 m: no calibration from it, one line saying how the map is off."""
    out, hidden = rendered
    data = yaml.safe_load((out / "markers.yaml").read_text())
    for m in data["markers"]:
        m["position"][0] += 10.0
    shifted = tmp_path / "shifted.yaml"
    shifted.write_text(yaml.safe_dump(data))
    code = _cli([out / "scenario.bag", "--markers", shifted, "--time-offset", hidden["camera_time_offset"], "--out",
                 tmp_path / "c.yaml", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1, err
    assert "the marker map does not fit this recording" in err[0], err
    assert re.search(r"the map looks shifted by \(\+(9\.9\d|10\.0\d), [-+]0\.\d\d, [-+]0\.\d\d\) m", err[0]), err
    assert "not calibrated" in err[0] and "--force" in err[0]
    assert not (tmp_path / "c.yaml").exists()
