"""The simulator CLI: help, argument errors, and a real run on TCP answered by the client."""
import os
import signal
import subprocess
import sys
import time

import pytest

from aruco_abs_orient.geocom.client import GeoComClient
from aruco_abs_orient.geocom.sim_cli import main, parse_faults
from aruco_abs_orient.geocom.simulator import FaultRates


def test_help_has_an_example(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "--pty" in out and "_port:=" in out and "garbage=" in out


@pytest.mark.parametrize("argv, message", [
    ([], "exactly one of --pty"),
    (["--pty", "--tcp", "0"], "exactly one of --pty"),
    (["--pty", "--profile", "loose"], "invalid choice: 'loose'"),
    (["--pty", "--model", "TS30"], "invalid choice: 'TS30'"),
])
def test_transport_choice_is_required(argv, message, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.parametrize("text, message", [
    ("bogus=1", "unknown item 'bogus=1'"), ("drop", "unknown item 'drop'"), ("drop=x", "not a number"),
    ("drop=2", "out of range"), ("garbage=-0.1", "out of range"),
])
def test_bad_faults_are_one_clear_line(text, message, capsys):
    assert main(["--tcp", "0", "--faults", text]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


def test_missing_trajectory_is_one_clear_line(tmp_path, capsys):
    assert main(["--pty", "--trajectory", str(tmp_path / "none.tum")]) == 2
    assert "none.tum" in capsys.readouterr().err


def test_parse_faults():
    assert parse_faults("garbage=0.02,lock_loss=0.5") == FaultRates(garbage=0.02, lock_loss=0.5)
    assert parse_faults("") == FaultRates()


def test_runs_on_tcp_with_a_tum_trajectory(tmp_path):
    tum = tmp_path / "prism.tum"
    tum.write_text("0 1 2 3 0 0 0 1\n10 11 2 3 0 0 0 1\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen([sys.executable, "-m", "aruco_abs_orient.geocom.sim_cli", "--tcp", "0", "--seed", "1",
                             "--profile", "lenient", "--trajectory", str(tum), "--truth", str(tmp_path / "truth.csv")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, universal_newlines=True)
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("socket://127.0.0.1:")
        with GeoComClient(url, timeout_s=1.0) as client:
            assert client.lock_in() == 0
            client.do_measure(2)
            r = client.get_coordinate().reading
            assert r.has_position and 1.0 <= r.east <= 11.0  # through the station's polar geometry: to 1e-9 m
            assert (r.north, r.height) == (pytest.approx(2.0, abs=1e-9), pytest.approx(3.0, abs=1e-9))
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)
    assert proc.returncode == 0
    lines = (tmp_path / "truth.csv").read_text().splitlines()
    assert lines[0].startswith("t_s,instrument_ms") and len(lines) == 2
    assert time.time() - float(lines[1].split(",")[0]) < 60


def test_strict_is_the_default_profile():
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen([sys.executable, "-m", "aruco_abs_orient.geocom.sim_cli", "--tcp", "0",
                             "--model", "TPS1200"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                            universal_newlines=True)
    try:
        url = proc.stdout.readline().strip()
        with GeoComClient(url, timeout_s=1.0) as client:
            assert client.instrument_name() == "TCRP1201+"
            assert client.lock_in(timeout_s=3.0) == 8714            # strict: LOCK mode is off
            assert client.power_search_next(timeout_s=3.0) == 5     # the TPS1200 model has no PowerSearch
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)
    assert proc.returncode == 0 and "TPS1200 simulator (strict)" in proc.stderr.read()
