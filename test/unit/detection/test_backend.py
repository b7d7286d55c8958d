"""detection/backend.py and params.py: the OpenCV adapter picks the API this OpenCV has, the function
API of OpenCV 4.2–4.6 finds the same markers at the same bearings (Debian's OpenCV in a subprocess),
and unknown dictionaries or parameters are refused by name."""
import os
import shutil
import subprocess

import cv2
import numpy as np
import pytest

from aruco_abs_orient.camera import angle_between, azel_to_bearing
from aruco_abs_orient.detection import ArucoBackend, DetectionError, DetectorParams, MarkerDetector
from aruco_abs_orient.synthetic.render import facing_marker, render_equirect

from .common import DEG, SRC, by_id, detector, true_centre


def test_unknown_dictionary_and_bad_params():
    with pytest.raises(DetectionError, match="DICT_9X9_1"):
        MarkerDetector("DICT_9X9_1")
    with pytest.raises(DetectionError, match="corner_refinement"):
        DetectorParams(corner_refinement="magic")
    with pytest.raises(DetectionError, match="seam_strip_deg"):
        DetectorParams(seam_strip_deg=-1.0)


# --------------------------------------------------------------------------- OpenCV APIs

def test_backend_picks_the_api_this_opencv_has():
    backend = ArucoBackend("DICT_4X4_50", DetectorParams())
    expected = "ArucoDetector" if hasattr(cv2.aruco, "ArucoDetector") else "function"
    assert backend.api == expected
    if not hasattr(cv2.aruco, "detectMarkers"):
        with pytest.raises(DetectionError, match="function API"):
            ArucoBackend("DICT_4X4_50", DetectorParams(), api="function")
    assert backend.codes.shape == (50, 4, 4) and backend.bits == 6


FUNCTION_API_PY = shutil.which("python3", path="/usr/bin")


def _has_function_api(python):
    if python is None:
        return False
    code = "import cv2, sys; sys.exit(0 if hasattr(cv2, 'aruco') and hasattr(cv2.aruco, 'detectMarkers') else 1)"
    return subprocess.run([python, "-c", code], capture_output=True).returncode == 0


@pytest.mark.skipif(not _has_function_api(FUNCTION_API_PY), reason="no OpenCV with the aruco function API")
def test_function_api_finds_the_same_markers(tmp_path):
    # Debian's OpenCV 4.6 (the API of Noetic's 4.2) runs the same module in a subprocess
    ms = [facing_marker(i, 0.19, d * azel_to_bearing(-2.0 + 1.1 * i, 0.05)) for i, d in enumerate([1.5, 3.0, 5.0])]
    img = render_equirect(1920, ms, seed=5)
    np.save(tmp_path / "frame.npy", img)
    script = (
        "import sys, json, numpy as np\n"
        "from aruco_abs_orient.detection import MarkerDetector\n"
        "det = MarkerDetector('DICT_4X4_50')\n"
        f"obs = det.detect(np.load({str(tmp_path / 'frame.npy')!r}))\n"
        "print(json.dumps({'api': det.backend.api, 'obs': [[o.id] + o.centre.tolist() for o in obs]}))\n"
    )
    env = dict(os.environ, PYTHONPATH=os.path.abspath(SRC))
    out = subprocess.run([FUNCTION_API_PY, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    import json

    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["api"] == "function"
    here = by_id(detector().detect(img))
    assert sorted(here) == [r[0] for r in res["obs"]] == [0, 1, 2]
    for r in res["obs"]:
        assert float(angle_between(np.array(r[1:]), true_centre(ms[r[0]]))) / DEG < 0.03
        assert float(angle_between(np.array(r[1:]), here[r[0]].centre)) / DEG < 0.01
