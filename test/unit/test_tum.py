"""tum.py: TUM round trips, bad files named with their line, interpolation against exact motion."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.transforms import matrix_to_quat, quat_to_matrix, rpy_to_matrix, yaw_of
from aruco_abs_orient.tum import Trajectory, TumError, read_tum, slerp, sorted_series, write_tum


def _constant_turn(stamps, rate=0.3, speed=1.0):
    """Exact motion: yaw = rate·t, position along x at ``speed``."""
    yaw = rate * stamps
    pos = np.stack([speed * stamps, np.zeros_like(stamps), np.full_like(stamps, 0.5)], -1)
    return Trajectory(stamps, pos, matrix_to_quat(rpy_to_matrix(0 * yaw, 0 * yaw, yaw)))


def test_round_trip(tmp_path):
    traj = _constant_turn(np.linspace(0, 10, 21) + 1.7e9)
    path = tmp_path / "t.tum"
    write_tum(str(path), traj, header="made by a test")
    back = read_tum(str(path))
    np.testing.assert_allclose(back.stamps, traj.stamps, atol=1e-9)
    np.testing.assert_allclose(back.positions, traj.positions, atol=1e-6)
    np.testing.assert_allclose(back.quats, traj.quats, atol=1e-9)
    assert path.read_text().startswith("# made by a test\n")
    assert not [p for p in tmp_path.iterdir() if p.name != "t.tum"]  # no temporary left behind


@pytest.mark.parametrize("line,what", [("1 2 3", "expected 8 fields"), ("1 2 3 4 5 6 7 x", "not a number"),
                                       ("1 2 3 nan 0 0 0 1", "NaN")])
def test_bad_lines_are_named(tmp_path, line, what):
    path = tmp_path / "bad.tum"
    path.write_text("# ok\n0 0 0 0 0 0 0 1\n" + line + "\n")
    with pytest.raises(TumError, match=r"bad\.tum:3: " + what):
        read_tum(str(path))


def test_missing_file():
    with pytest.raises(TumError, match="cannot read"):
        read_tum("/nonexistent/x.tum")


@given(st.floats(0.0, 10.0))
def test_interpolation_is_exact_for_constant_rates(t):
    traj = _constant_turn(np.linspace(0, 10, 11))
    p, q, valid = traj.interpolate(t)
    assert bool(valid)
    np.testing.assert_allclose(p, [t, 0, 0.5], atol=1e-12)
    assert math.remainder(float(yaw_of(quat_to_matrix(q))) - 0.3 * t, 2 * math.pi) == pytest.approx(0, abs=1e-12)


def test_interpolation_flags_outside_and_takes_the_short_way():
    traj = _constant_turn(np.array([0.0, 1.0]), rate=0.0)
    _, _, valid = traj.interpolate(np.array([-0.1, 0.5, 1.1]))
    assert valid.tolist() == [False, True, False]
    q0 = matrix_to_quat(rpy_to_matrix(0, 0, math.radians(179)))
    q1 = -matrix_to_quat(rpy_to_matrix(0, 0, math.radians(-179)))  # same rotation, other sign
    mid = slerp(q0, q1, 0.5)
    assert abs(math.degrees(float(yaw_of(quat_to_matrix(mid))))) == pytest.approx(180.0, abs=1e-9)


def test_sorted_series_sorts_stably_and_names_the_series_in_the_given_error():
    class MyError(ValueError):
        pass

    t, v = sorted_series([3.0, 1.0, 2.0, 1.0], [30.0, 10.0, 20.0, 11.0], "yaw", MyError)
    np.testing.assert_array_equal(t, [1.0, 1.0, 2.0, 3.0])
    np.testing.assert_array_equal(v, [10.0, 11.0, 20.0, 30.0])   # equal stamps keep their order
    t, xy = sorted_series([2.0, 1.0], [[2.0, 2.5], [1.0, 1.5]], "track", MyError, ncols=2)
    np.testing.assert_array_equal(xy, [[1.0, 1.5], [2.0, 2.5]])
    assert sorted_series([], [], "empty", MyError, ncols=2)[1].shape == (0, 2)
    with pytest.raises(MyError, match="yaw: 2 stamps but 3 values"):
        sorted_series([1.0, 2.0], [1.0, 2.0, 3.0], "yaw", MyError)
    with pytest.raises(MyError, match="track: NaN or inf"):
        sorted_series([1.0, float("nan")], [[0.0, 0.0], [1.0, 1.0]], "track", MyError, ncols=2)


def _readers():
    from aruco_abs_orient.calibration import load_calibration
    from aruco_abs_orient.markers import MarkerMap
    from aruco_abs_orient.offline.prism import read_prism
    from aruco_abs_orient.params import load_params
    from aruco_abs_orient.survey import read_gsi, read_points

    return {"survey": read_points, "gsi": read_gsi, "prism": read_prism,
            "prism gsi": lambda p: read_prism(p, "gsi"), "tum": read_tum, "marker map": MarkerMap.load,
            "calibration": load_calibration, "params": load_params}


READERS = sorted(_readers())
# random bytes, and random bytes behind a start each reader recognises (a GSI word, a CSV row, YAML)
PREFIXES = [b"", b"*110001+0000000000000007 81..00+", b"7,1.5,2.5,", b"markers:\n  - {id: 1, position: [",
            b"\xef\xbb\xbf", b"\xff\xfe"]


@settings(max_examples=40)
@given(reader=st.sampled_from(READERS), prefix=st.sampled_from(PREFIXES), data=st.binary(min_size=1, max_size=300))
def test_random_bytes_to_any_reader_give_one_line_naming_the_file(tmp_path_factory, reader, prefix, data):
    """Whatever the bytes, a reader returns or raises the package's error: one line that names the file."""
    from aruco_abs_orient.errors import AbsOrientError

    path = tmp_path_factory.mktemp("fuzz") / "input.dat"
    path.write_bytes(prefix + data)
    try:
        _readers()[reader](str(path))
    except AbsOrientError as e:
        assert str(path) in str(e) and "\n" not in str(e), str(e)


@pytest.mark.parametrize("reader", READERS)
def test_a_binary_file_is_named_as_one(tmp_path, reader):
    from aruco_abs_orient.errors import AbsOrientError

    path = tmp_path / "x.bin"
    path.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(AbsOrientError, match=r"x\.bin: not a .* file: control byte 0x00 at offset 0"):
        _readers()[reader](str(path))


def test_a_decimal_comma_tum_is_refused_not_misread(tmp_path):
    path = tmp_path / "vo.tum"
    path.write_text("12,5 3 4 5 0 0 0 1\n")
    with pytest.raises(TumError, match=r"vo\.tum:1: commas between blank-separated fields \(a decimal comma\?\)"):
        read_tum(str(path))
    path.write_text("12.5,3,4,5,0,0,0,1\n")  # a comma-separated TUM file still reads
    assert read_tum(str(path)).stamps.tolist() == [12.5]


def test_a_write_makes_its_directory_or_names_the_file(tmp_path):
    from aruco_abs_orient.errors import InputFileError
    from aruco_abs_orient.tum import WriteError, atomic_write_text

    atomic_write_text(str(tmp_path / "new" / "dir" / "a.txt"), "x\n")
    assert (tmp_path / "new" / "dir" / "a.txt").read_text() == "x\n"
    (tmp_path / "file").write_text("")
    with pytest.raises(WriteError, match=r"file/b\.txt: cannot write: ") as e:
        atomic_write_text(str(tmp_path / "file" / "b.txt"), "y")
    assert isinstance(e.value, InputFileError)  # the CLI's one line
