"""detection/jpegrows.py: frames decoded in part (the rows tracking reads), against the same decoder's whole frame
and against images.decode_jpeg (simplejpeg's libjpeg-turbo, or OpenCV's on a Noetic robot), on frames rendered by
synthetic/render.py and encoded by OpenCV as a camera would (grey and colour)."""
import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.camera import azel_to_bearing
from aruco_abs_orient.detection import DetectionError, decode_jpeg
from aruco_abs_orient.detection.jpegrows import RowFrame, RowsMissing, decode_jpeg_rows, need_rows, row_decoder
from aruco_abs_orient.synthetic.render import encode_jpeg, facing_marker, render_equirect

H = 480


@pytest.fixture(scope="module")
def frames():
    """A grey and a colour JPEG of a rendered 960×480 frame with markers, and the grey frame decoded whole."""
    grey = render_equirect(2 * H, [facing_marker(i, 0.19, 2.0 * azel_to_bearing(0.6 * i, 0.3 - 0.2 * i))
                                   for i in range(4)], seed=5)
    colour = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    colour[:, :, 2] = cv2.add(colour[:, :, 2], 40)   # a tint: Cb and Cr carry something
    return encode_jpeg(grey, 90), cv2.imencode(".jpg", colour, [cv2.IMWRITE_JPEG_QUALITY, 85])[1].tobytes()


def test_the_decoder_is_built_here_and_decodes_as_the_others(frames):
    """`make setup` installs what it needs (a C compiler, libjpeg's headers): a run here decodes rows; its whole
    frame is decode_jpeg's (the same fast integer IDCT as simplejpeg; OpenCV's exact one differs by rounding)."""
    lib, why = row_decoder()
    assert lib is not None, why
    for data in frames:
        diff = np.abs(decode_jpeg_rows(data, None).astype(int) - decode_jpeg(data))
        assert np.percentile(diff, 99) <= 2 and diff.max() <= 12, (np.percentile(diff, 99), diff.max())


@settings(max_examples=40, deadline=None)
@given(r0=st.integers(-5, H + 5), n=st.integers(0, H + 10), colour=st.booleans())
def test_rows_are_those_of_the_whole_decode_and_the_rest_is_zero(frames, r0, n, colour):
    data = frames[colour]
    whole = decode_jpeg_rows(data, None)
    got = decode_jpeg_rows(data, (r0, r0 + n))
    assert got.shape == whole.shape and got.dtype == np.uint8
    if isinstance(got, RowFrame):
        a, b = got.rows
        assert (a, b) == (max(r0, 0), min(r0 + n, H)) and 0 <= a < b <= H and (a, b) != (0, H)
        assert np.array_equal(np.asarray(got)[a:b], whole[a:b])
        assert not np.asarray(got)[:a].any() and not np.asarray(got)[b:].any()
        assert np.array_equal(got.complete(), whole) and got.completed
    else:  # the whole frame: asked for all of it, or for nothing
        assert (max(r0, 0) == 0 and r0 + n >= H) or r0 + n <= max(r0, 0) or r0 >= H
        assert np.array_equal(got, whole)


@settings(max_examples=60, deadline=None)
@given(a=st.integers(0, H - 1), span=st.integers(1, H), r0=st.integers(-10, H + 10), m=st.integers(0, H))
def test_need_rows_raises_exactly_for_rows_not_decoded(frames, a, span, r0, m):
    got = decode_jpeg_rows(frames[0], (a, a + span))
    rows = got.rows if isinstance(got, RowFrame) else (0, H)
    inside = rows[0] <= max(r0, 0) and min(r0 + m, H) <= rows[1]
    if inside:
        need_rows(got, r0, r0 + m)
    else:
        with pytest.raises(RowsMissing):
            need_rows(got, r0, r0 + m)
    need_rows(decode_jpeg(frames[0]), r0, r0 + m)   # a frame decoded whole: never
    assert not isinstance(got[:10], RowFrame) or got[:10].rows is None   # a slice is not the frame's rows


def test_a_corrupt_or_truncated_jpeg_is_an_error(frames):
    data = frames[0]
    with pytest.raises(DetectionError, match="not a whole JPEG"):
        decode_jpeg_rows(data[: len(data) // 2], (0, 10))      # cut: its damage lies below the rows asked
    with pytest.raises(DetectionError, match="corrupt"):
        decode_jpeg_rows(data[: len(data) // 2] + b"\xff\xd9", (0, H))
    with pytest.raises(DetectionError, match="not a whole JPEG"):
        decode_jpeg_rows(b"\x00" * 100, None)
    with pytest.raises(DetectionError, match="corrupt"):   # libjpeg cannot read it: decode_jpeg names it
        decode_jpeg_rows(b"\xff\xd8" + b"\x00" * 100 + b"\xff\xd9", (0, 10))
