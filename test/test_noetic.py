"""The package on a ROS Noetic robot's Python stack (issue 19), run from the main venv.

``make setup`` builds ``.venv-noetic`` from a Python 3.8 with Ubuntu 20.04's versions
(requirements-noetic.txt: numpy 1.17.4, OpenCV 4.2 with the old aruco function API, PyYAML 5.3.1,
pyserial 3.4, scipy 1.3.3, matplotlib 3.1.2, rosbags 0.9.23). Here:

- that venv really has those versions, and its OpenCV only the function API;
- the core unit tests pass in it (:data:`CORE_TESTS`, in a subprocess); only tests that need ROS
  (rospy, rosbag) may skip there, and the counts are printed;
- OpenCV 4.2's function API finds the same markers as 4.11's ``ArucoDetector`` on the same rendered
  frames (seam, poles, 0.5–12 m), bearings within 0.005° of each other and near the rendered truth.

Without a Python 3.8 these tests fail and say how to get one: they never pass silently.
"""
import json
import math
import os
import re
import subprocess
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from aruco_abs_orient.camera import angle_between, azel_to_bearing
from aruco_abs_orient.detection import MarkerDetector
from aruco_abs_orient.synthetic.render import facing_marker, render_equirect

ROOT = Path(__file__).resolve().parents[1]
NOETIC_PY = ROOT / ".venv-noetic" / "bin" / "python"
HOW_TO_GET_ONE = (
    "needs the venv .venv-noetic, built by `make setup` from a Python 3.8: install one with "
    "`pyenv install 3.8` (or on Ubuntu 20.04 `apt install python3.8-venv`; or point $AAO_PYTHON38 at a "
    "python3.8), then run `make setup` again (its log says what it found)")
#: the versions of Ubuntu 20.04's python3-* packages a Noetic robot runs (requirements-noetic.txt)
NOETIC_VERSIONS = {"python": "3.8", "numpy": "1.17.4", "cv2": "4.2.0", "yaml": "5.3.1", "serial": "3.4",
                   "scipy": "1.3.3", "matplotlib": "3.1.2", "rosbags": "0.9.23"}
#: the core unit tests run on those versions (paths in test/unit/; a folder: all its tests): everything
#: ROS-free but the docs and the renderer's own test (which checks the renderer with OpenCV ≥ 4.7's
#: ArucoDetector; detection covers the renderer on 4.2)
CORE_TESTS = ["test_camera.py", "test_transforms.py", "test_markers.py", "test_tum.py", "detection",
              "test_tracking.py", "test_solver.py", "test_correction.py", "test_filter_core.py",
              "test_filter_startup.py", "test_filter_recovery.py", "test_startup_anywhere.py",
              "test_nodestate.py", "test_nodecontrol.py", "test_debugview.py", "test_plots.py", "test_figures.py",
              "timesync",
              "calibration", "offline/test_calibrate.py", "test_pipeline_rolling_shutter.py", "test_evaluation.py",
              "geocom/test_protocol.py", "geocom/test_dispatch.py", "geocom/test_client.py", "geocom/test_clock.py",
              "geocom/test_tracker.py",
              "geocom/test_sim_cli.py", "synthetic/test_config.py",
              "synthetic/test_scenario.py", "synthetic/test_bag.py", "offline/test_process.py", "offline/test_sync.py",
              "offline/test_evaluate.py", "offline/test_commandlines.py", "test_layering.py",
              "test_pipeline.py", "test_prismbuffer.py", "test_params.py", "test_paramspec.py", "test_survey.py",
              "test_table.py", "test_mapcheck.py", "mapping"]
#: the only reasons a test may skip there: it needs ROS, or geocompy (the independent GeoCOM client of the
#: tests needs Python ≥ 3.11: it checks the simulator in the main venv)
#: CORE_TESTS in two parts run side by side (make test: test/conftest.py gives each its own worker), about
#: equally long: the calibration's least squares and process's scenarios (≈ 550 s at load 7), the rest (≈ 450 s)
CORE_PARTS = (["calibration", "offline/test_process.py"],
              [name for name in CORE_TESTS if name not in ("calibration", "offline/test_process.py")])
ROS_ONLY = re.compile(r"\brospy\b|\brosbag\b|\bROS\b|\bgeocompy\b")
DEG = math.pi / 180.0


def noetic_env():
    """The environment of a .venv-noetic subprocess: nothing of ROS's or Debian's Python 3.11 paths."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYENV_VERSION")}
    env["MPLBACKEND"] = "Agg"
    return env


def noetic_python() -> str:
    if not NOETIC_PY.is_file():
        pytest.fail(f"no Python 3.8 venv at {NOETIC_PY}: this test {HOW_TO_GET_ONE}", pytrace=False)
    return str(NOETIC_PY)


def run_noetic(args, timeout, cwd=ROOT):
    return subprocess.run([noetic_python()] + list(args), cwd=str(cwd), env=noetic_env(), timeout=timeout,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def test_the_venv_has_noetics_versions():
    code = ("import json, platform, cv2, numpy, yaml, serial, scipy, matplotlib, rosbags\n"
            "from importlib.metadata import version\n"
            "v = {'python': '.'.join(platform.python_version_tuple()[:2]), 'numpy': numpy.__version__,\n"
            "     'cv2': cv2.__version__, 'yaml': yaml.__version__, 'serial': serial.VERSION,\n"
            "     'scipy': scipy.__version__, 'matplotlib': matplotlib.__version__, 'rosbags': version('rosbags')}\n"
            "a = cv2.aruco\n"
            "old = ('detectMarkers', 'DetectorParameters_create', 'drawMarker')\n"
            "print(json.dumps({'versions': v, 'ArucoDetector': hasattr(a, 'ArucoDetector'),\n"
            "                  'generateImageMarker': hasattr(a, 'generateImageMarker'),\n"
            "                  'function API': all(hasattr(a, f) for f in old)}))\n")
    out = run_noetic(["-c", code], timeout=120)
    assert out.returncode == 0, f"{NOETIC_PY} cannot import its requirements ({HOW_TO_GET_ONE}):\n{out.stdout}"
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["versions"] == NOETIC_VERSIONS
    assert res["function API"] and not res["ArucoDetector"] and not res["generateImageMarker"]


class CoreRun:
    """The core unit tests in .venv-noetic, as a subprocess (under `make test`'s two workers it runs beside
    the rostests, test/conftest.py: most of its time is waiting on simulated instruments and clocks)."""

    def __init__(self, names=CORE_TESTS):
        self.dir = Path(tempfile.mkdtemp(prefix="noetic-core-"))
        self.report = self.dir / "junit.xml"
        files = [str(ROOT / "test" / "unit" / name) for name in names]
        self.log = self.dir / "pytest.log"
        with open(str(self.log), "w") as log:  # the child keeps its own descriptor
            self.proc = subprocess.Popen(
                [noetic_python(), "-m", "pytest", "-q", "-p", "no:cacheprovider", "-o", "junit_family=xunit1",
                 f"--junitxml={self.report}", f"--basetemp={self.dir / 'tmp'}"] + files,
                cwd=str(ROOT), env=noetic_env(), stdout=log, stderr=subprocess.STDOUT, text=True)

    def wait(self, timeout: float):
        """(exit status, the output's last 40 lines)."""
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.stop()
            code = "timed out"
        return code, "\n".join(self.log.read_text().splitlines()[-40:])

    def stop(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def test_the_core_parts_are_the_core_tests():
    assert sorted(sum(CORE_PARTS, [])) == sorted(CORE_TESTS)


@pytest.mark.slow
@pytest.mark.timeout(2400)
@pytest.mark.parametrize("part", range(len(CORE_PARTS)))
def test_core_unit_tests_pass_on_noetics_versions(part, capsys):
    run = CoreRun(CORE_PARTS[part])
    code, tail = run.wait(timeout=2300)
    report = run.report
    assert report.is_file(), f"the Python 3.8 pytest run wrote no report (exit {code}):\n{tail}"
    suite = ET.parse(str(report)).getroot()
    suite = suite if suite.tag == "testsuite" else suite.find("testsuite")
    total, failed, errors, skipped = (int(suite.get(k)) for k in ("tests", "failures", "errors", "skipped"))
    skips = {f"{case.get('classname')}::{case.get('name')}": case.find("skipped").get("message", "")
             for case in suite.iter("testcase") if case.find("skipped") is not None}
    with capsys.disabled():
        print(f"\n.venv-noetic (Python 3.8, numpy 1.17.4, OpenCV 4.2): {total - skipped} core unit tests ran, "
              f"{skipped} skipped (need ROS or geocompy), {failed + errors} failed, "
              f"in {float(suite.get('time')):.0f} s")
    assert code == 0 and failed == errors == 0, f"core unit tests fail on Noetic's versions:\n{tail}"
    not_ros = {k: v for k, v in skips.items() if not ROS_ONLY.search(v)}
    assert not not_ros, f"only tests that need ROS may skip on Noetic's versions: {not_ros}"
    ran = {case.get("file", "") for case in suite.iter("testcase") if case.find("skipped") is None}
    missing = [name for name in CORE_PARTS[part] if not any(f.startswith(f"test/unit/{name}") for f in ran)]
    assert not missing, f"no test of {missing} ran: files missing from the run?\n{tail}"


#: run by .venv-noetic's python (pyserial 3.4): a socket:// peer that hangs up at once (a serial-to-TCP
#: bridge of the MS60 during an outage); the hang-up arrives before the port's open() flushes its input
HUNG_UP_PEER = (
    "import os, socket, threading, time\n"
    "from aruco_abs_orient.geocom.client import GeoComClient\n"
    "srv = socket.socket(); srv.bind(('127.0.0.1', 0)); srv.listen(4)\n"
    "def serve():\n"
    "    while True:\n"
    "        c, _ = srv.accept(); c.close()\n"
    "threading.Thread(target=serve, daemon=True).start()\n"
    "connect = socket.create_connection\n"
    "def late(*a, **k):\n"
    "    s = connect(*a, **k); time.sleep(0.2); return s\n"
    "socket.create_connection = late\n"
    "opened = threading.Event()\n"
    "def client():\n"
    "    GeoComClient('socket://127.0.0.1:%d' % srv.getsockname()[1]).close(); opened.set()\n"
    "threading.Thread(target=client, daemon=True).start()\n"
    "print('opened' if opened.wait(5.0) else 'open() still spinning after 5 s', flush=True)\n"
    "os._exit(0)\n")


def test_geocom_socket_port_opens_when_the_peer_has_hung_up_on_pyserial_3_4():
    out = run_noetic(["-c", HUNG_UP_PEER], timeout=60)
    assert out.returncode == 0, out.stdout
    assert out.stdout.strip().splitlines()[-1] == "opened"


# --------------------------------------------------------------------------- the two OpenCV ArUco APIs

def api_comparison_frames():
    """Rendered 3840×1920 frames ('realistic': blur, noise, JPEG 85) with their markers: 1–12 m spread
    in azimuth and elevation; markers straddling the ±180° seam and at ±70° elevation; close ones (0.5 m)
    and high ones (45–60°); a ring at 12 m."""
    rng = np.random.default_rng(19)
    scenes = [
        [facing_marker(i, 0.19, d * azel_to_bearing(-3.0 + 0.55 * i, rng.uniform(-0.35, 0.35)),
                       roll=rng.uniform(-0.6, 0.6)) for i, d in enumerate([1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11])],
        [facing_marker(i, 0.19, d * azel_to_bearing(math.pi + rng.uniform(-0.3, 0.3) * 0.19 / d, el * DEG),
                       roll=rng.uniform(-0.6, 0.6))
         for i, (d, el) in enumerate([(0.6, -38), (1.0, -12), (2.0, 8), (4.0, 22), (8.0, 36)])]
        + [facing_marker(10 + i, 0.19, 1.5 * azel_to_bearing(-3.0 + 1.0 * i, (70.0 if i % 2 else -70.0) * DEG),
                         roll=rng.uniform(-0.6, 0.6)) for i in range(6)],
        [facing_marker(i, 0.19, d * azel_to_bearing(-2.8 + 0.9 * i, el * DEG), roll=rng.uniform(-0.6, 0.6))
         for i, (d, el) in enumerate([(0.5, 10), (0.5, -35), (0.5, 50), (1.0, 45), (1.0, -52), (2.0, 60), (3.0, -48)])],
        [facing_marker(i, 0.19, 12.0 * azel_to_bearing(-3.0 + 0.6 * i, rng.uniform(-0.3, 0.3)),
                       roll=rng.uniform(-0.7, 0.7)) for i in range(10)],
    ]
    return [(render_equirect(3840, ms, seed=190 + k), ms) for k, ms in enumerate(scenes)]


#: run by .venv-noetic's python: detect in the frames given as .npy files, print the bearings as JSON
DETECT_IN_FILES = (
    "import json, sys, numpy as np\n"
    "from aruco_abs_orient.detection import MarkerDetector\n"
    "det = MarkerDetector('DICT_4X4_50')\n"
    "print(json.dumps({'api': det.backend.api, 'frames': [{o.id: o.centre.tolist() for o in det.detect(np.load(f))}\n"
    "                                                      for f in sys.argv[1:]]}))\n")


def test_opencv_4_2_function_api_finds_the_same_markers_as_arucodetector(tmp_path):
    frames = api_comparison_frames()
    files = []
    for k, (img, _) in enumerate(frames):
        files.append(str(tmp_path / f"frame{k}.npy"))
        np.save(files[-1], img)
    out = run_noetic(["-c", DETECT_IN_FILES] + files, timeout=600)
    assert out.returncode == 0, out.stdout
    old = json.loads(out.stdout.strip().splitlines()[-1])
    assert old["api"] == "function"
    det = MarkerDetector("DICT_4X4_50", api="ArucoDetector")
    far_found = far = 0
    for k, (img, ms) in enumerate(frames):
        new = {o.id: o.centre for o in det.detect(img)}
        old_k = {int(i): np.array(c) for i, c in old["frames"][k].items()}
        assert sorted(old_k) == sorted(new), f"frame {k}: OpenCV 4.2 found {sorted(old_k)}, 4.11 {sorted(new)}"
        truth = {m.id: m.center / np.linalg.norm(m.center) for m in ms}
        for i, centre in new.items():
            assert float(angle_between(old_k[i], centre)) / DEG < 0.005, f"frame {k}, marker {i}"
            assert float(angle_between(centre, truth[i])) / DEG < 0.06, f"frame {k}, marker {i} is not where rendered"
        missed = [m for m in ms if m.id not in new]
        assert all(np.linalg.norm(m.center) > 11.9 for m in missed), f"frame {k}: missed {[m.id for m in missed]}"
        far += sum(np.linalg.norm(m.center) > 11.9 for m in ms)
        far_found += sum(np.linalg.norm(m.center) > 11.9 for m in ms if m.id in new)
    assert far_found >= 0.8 * far, f"only {far_found} of {far} markers at 12 m found"
