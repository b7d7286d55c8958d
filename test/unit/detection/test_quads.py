"""quiet_zone_contrast, the rescue's first look at a rejected quad: every marker drawn by OpenCV's own generator,
warped into an image by a random homography, that the refinement and the reading would read from corners a pixel
off (as OpenCV's unrefined ones are) reads well above the rescue's threshold; a texture without a dark square in
a bright ring reads as about 0, a linear ramp as exactly 0 (the rings are centrally symmetric), a white square on
black as negative."""
import math

import cv2
import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from aruco_abs_orient.detection import DetectorParams, MarkerDetector
from aruco_abs_orient.detection.quads import decode_quads, image_sampler, quiet_zone_contrast, refine_quads

CELLS = 6  # a 4×4 code: its side in cells, the black border included
THRESHOLD = DetectorParams().rescue_min_contrast
CODES = MarkerDetector("DICT_4X4_50").backend.codes


def marker_quad(rng, side, centre, tilt):
    """The black square's corners (4, 2): a square of ``side`` px turned at random, foreshortened by ``tilt``."""
    a = rng.uniform(0.0, 2.0 * math.pi)
    d = 0.5 * side * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)
    d[:, 0] *= math.cos(tilt)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    return np.asarray(centre) + d @ rot.T


def draw_marker(rng, quad, black, white, size=200):
    """A textured image with DICT_4X4_50 marker ``rng``-chosen, its one-cell white quiet zone, its black
    square's corners at ``quad`` (OpenCV draws it; a homography places it), blurred by a lens's worth."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    cell_px = 20
    generate = getattr(cv2.aruco, "generateImageMarker", None) or cv2.aruco.drawMarker  # OpenCV 4.7+, 4.2
    code = generate(dictionary, int(rng.integers(0, 50)), CELLS * cell_px)
    tile = np.full(((CELLS + 2) * cell_px,) * 2, 255, np.uint8)
    tile[cell_px:-cell_px, cell_px:-cell_px] = code
    tile = (black + (white - black) * (tile.astype(np.float32) / 255.0)).astype(np.float32)
    src = np.float32([[cell_px, cell_px], [(CELLS + 1) * cell_px, cell_px],
                      [(CELLS + 1) * cell_px, (CELLS + 1) * cell_px], [cell_px, (CELLS + 1) * cell_px]])
    H = cv2.getPerspectiveTransform(src, np.float32(quad))
    background = cv2.GaussianBlur(rng.uniform(60, 200, (size, size)).astype(np.float32), (0, 0), 3.0)
    mask = cv2.warpPerspective(np.ones_like(tile), H, (size, size), flags=cv2.INTER_LINEAR)
    warped = cv2.warpPerspective(tile, H, (size, size), flags=cv2.INTER_AREA)
    return cv2.GaussianBlur(mask * warped + (1 - mask) * background, (0, 0), 0.7)


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), side=st.floats(8.0, 40.0), tilt=st.floats(0.0, 1.0),
       contrast=st.floats(30.0, 230.0))
@example(seed=1, side=30.0, tilt=0.3, contrast=200.0)
def test_every_marker_the_rescue_reads_passes_its_first_look(seed, side, tilt, contrast):
    """The rescue skips a quad below the threshold before refining it: every marker that the refinement and the
    strict reading would have read, from corners a pixel off, must read well above it (over 3000 draws: ≥ 41
    grey levels, against 10)."""
    rng = np.random.default_rng(seed)
    black = rng.uniform(0.0, 255.0 - contrast)
    quad = marker_quad(rng, side, (100.0, 100.0), tilt)
    sample = image_sampler(draw_marker(rng, quad, black, black + contrast))
    off = quad + rng.uniform(-1.0, 1.0, (4, 2))          # OpenCV's corners, before any refinement
    refined = refine_quads(sample, off[None], CELLS)
    read = not np.isnan(refined).any() and decode_quads(sample, refined, CODES)[0] is not None
    assert read or side < 30.0 or contrast < 200.0      # a big clear marker is read: the check above is not empty
    if read:
        assert quiet_zone_contrast(sample, off[None], CELLS)[0] >= 2.0 * THRESHOLD


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), gx=st.floats(-3.0, 3.0), gy=st.floats(-3.0, 3.0),
       side=st.floats(8.0, 60.0), shear=st.floats(-0.5, 0.5))
def test_a_ramp_reads_as_zero_and_a_white_square_on_black_as_negative(seed, gx, gy, side, shear):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:200, 0:200].astype(np.float32)
    ramp = 128.0 + gx * (x - 100.0) + gy * (y - 100.0)
    # a parallelogram: its cell centres are symmetric about its centre, so a linear ramp averages out exactly
    e1 = side * np.array([1.0, 0.0])
    e2 = side * np.array([shear, 1.0])
    a = rng.uniform(0.0, 2.0 * math.pi)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    quad = 100.0 + (np.array([-0.5 * e1 - 0.5 * e2, 0.5 * e1 - 0.5 * e2, 0.5 * e1 + 0.5 * e2,
                              -0.5 * e1 + 0.5 * e2]) @ rot.T)
    assert abs(quiet_zone_contrast(image_sampler(ramp), quad[None], CELLS)[0]) < 1e-3
    inverted = 255.0 - draw_marker(rng, quad, 20.0, 220.0)
    assert quiet_zone_contrast(image_sampler(inverted), quad[None], CELLS)[0] < -2.0 * THRESHOLD


def test_texture_reads_near_zero():
    """Quads at random on a blurred random texture: contrast centred on 0, almost never past the rescue's
    threshold (a marker's, above, is several times it)."""
    rng = np.random.default_rng(7)
    img = cv2.GaussianBlur(rng.uniform(0, 255, (400, 400)).astype(np.float32), (0, 0), 1.5)
    quads = np.array([marker_quad(rng, rng.uniform(10, 40), rng.uniform(60, 340, 2), rng.uniform(0, 1))
                      for _ in range(2000)])
    c = quiet_zone_contrast(image_sampler(img), quads, CELLS)
    assert abs(float(np.mean(c))) < 1.0 and float(np.mean(np.abs(c) >= THRESHOLD)) < 0.05, (np.mean(c), np.std(c))
    assert quiet_zone_contrast(image_sampler(img), np.zeros((0, 4, 2)), CELLS).shape == (0,)
