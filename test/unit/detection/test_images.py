"""detection/images.py: frame validation and JPEG decoding (simplejpeg and the OpenCV-only path of
Noetic robots), on frames rendered by synthetic/render.py."""
import sys

import cv2
import numpy as np
import pytest

from aruco_abs_orient.camera import angle_between, azel_to_bearing
from aruco_abs_orient.detection import DetectionError, decode_jpeg, to_grey
from aruco_abs_orient.synthetic.render import encode_jpeg, facing_marker, render_equirect

from .common import detector

# --------------------------------------------------------------------------- bad input

def test_image_validation():
    with pytest.raises(DetectionError, match="empty"):
        to_grey(np.zeros((0, 0), np.uint8))
    with pytest.raises(DetectionError, match="2:1"):
        to_grey(np.zeros((100, 150), np.uint8))
    with pytest.raises(DetectionError, match="uint8"):
        to_grey(np.zeros((100, 200), np.float32))
    with pytest.raises(DetectionError, match="numpy"):
        to_grey(b"abc")
    with pytest.raises(DetectionError, match="shape"):
        to_grey(np.zeros((100, 200, 2), np.uint8))
    with pytest.raises(DetectionError, match="cam0"):
        detector().detect(np.zeros((10, 10), np.uint8), what="cam0")
    bgr = np.zeros((50, 100, 3), np.uint8)
    bgr[..., 2] = 200
    grey = to_grey(bgr)
    assert grey.shape == (50, 100) and int(grey[0, 0]) == int(round(0.299 * 200))
    assert to_grey(np.zeros((50, 100, 4), np.uint8)).shape == (50, 100)


def test_colour_and_grey_frames_give_the_same_markers():
    m = facing_marker(7, 0.19, 2.0 * azel_to_bearing(0.5, 0.1))
    grey = render_equirect(1920, [m], seed=3)
    colour = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    a, b = detector().detect(grey), detector().detect(colour)
    assert [o.id for o in a] == [o.id for o in b] == [7]
    assert float(angle_between(a[0].centre, b[0].centre)) < 1e-9


def test_decode_jpeg(monkeypatch):
    img = render_equirect(960, [], seed=1, profile="clean")
    data = encode_jpeg(img, 95)
    full = decode_jpeg(data)
    assert full.shape == img.shape and full.dtype == np.uint8
    assert np.abs(full.astype(int) - img).mean() < 2.0
    assert decode_jpeg(data, reduce=2).shape == (240, 480)
    for bad in (b"", b"not a jpeg at all", data[: len(data) // 2], data[:200] + b"\x00" * 500):
        with pytest.raises(DetectionError, match="frame 17"):
            decode_jpeg(bad, what="frame 17")
    with pytest.raises(DetectionError, match="reduce"):
        decode_jpeg(data, reduce=3)
    # the OpenCV-only path (Noetic robots without simplejpeg) decodes the same pixels but for the fast
    # IDCT's rounding (a few grey levels at most)
    monkeypatch.setitem(sys.modules, "simplejpeg", None)
    exact = decode_jpeg(data)
    assert exact.shape == full.shape
    diff = np.abs(exact.astype(int) - full)
    assert diff.max() <= 6 and diff.mean() < 0.6
    assert decode_jpeg(data, reduce=2).shape == (240, 480)
    with pytest.raises(DetectionError, match="corrupt"):
        decode_jpeg(data[: len(data) // 2])
