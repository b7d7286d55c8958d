"""offline/commandlines.py: the next command a tool suggests is one a shell runs as it is, and it detects about
ten images a second whatever the camera's rate."""

import shlex

import pytest

from aruco_abs_orient.offline.commandlines import calibrate_command, calibration_every, process_command


@pytest.mark.parametrize("rate, every", [(0.0, 1), (5.0, 1), (10.0, 1), (15.0, 2), (30.0, 3), (60.0, 6)])
def test_about_ten_images_a_second(rate, every):
    assert calibration_every(rate) == every
    words = shlex.split(calibrate_command("run 1.bag", "site/markers.yaml", 0.36712, rate))
    assert words[:3] == ["aruco-abs-orient", "calibrate", "run 1.bag"]
    assert words[words.index("--time-offset") + 1] == "0.3671"
    assert ("--every" in words) == (every > 1)
    if every > 1:
        assert words[words.index("--every") + 1] == str(every)
    assert words[words.index("--out") + 1] == "site/calibration.yaml"


def test_the_process_line_quotes_its_paths():
    words = shlex.split(process_command("my run.bag", shlex.quote("a b/markers.yaml"), -0.5, "a b/cal.yaml"))
    assert words == ["aruco-abs-orient", "process", "my run.bag", "--markers", "a b/markers.yaml", "--out",
                     "results/my run", "--time-offset", "-0.5000", "--calibration", "a b/cal.yaml"]
