"""solver.py against exact synthetic geometry built here from transforms.py.

Truth: base_link pose (R = Rz·Ry·Rx, p), static camera and prism lever arms, surveyed markers.
Exact bearings are the markers seen from the camera; noisy ones are perturbed by known σ, and
the propagated covariances are checked against Monte-Carlo scatter (normalised errors std ≈ 1).
"""

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from aruco_abs_orient.posefit import attitude_from_markers, resection
from aruco_abs_orient.solver import (
    DegenerateGeometryError,
    FitSettings,
    Mounting,
    NoiseModel,
    SolverError,
    fuse_yaws,
    yaw_from_marker,
)
from aruco_abs_orient.transforms import make_T, matrix_to_rpy, rot_x, rot_y, rpy_to_matrix, wrap_angle

finite = {"allow_nan": False, "allow_infinity": False}
yaws = st.floats(-math.pi, math.pi, **finite)
tilts = st.floats(-0.2, 0.2, **finite)
seeds = st.integers(0, 2 ** 32 - 1)


class Scene:
    """A base_link pose, lever arms and markers at 1–20 m from the camera (metres, radians), each farther
    than twice the camera–prism lever arm, so it lies outside the lever-arm sphere around the prism
    where one marker's yaw has no unique solution (tested on its own below)."""

    def __init__(self, seed, roll, pitch, yaw, n_markers):
        rng = np.random.default_rng(seed)
        self.rng = rng
        self.roll, self.pitch, self.yaw = roll, pitch, yaw
        self.R = rpy_to_matrix(roll, pitch, yaw)
        self.p = rng.uniform(-30, 30, 3)
        self.R_bc = rpy_to_matrix(*rng.uniform(-0.1, 0.1, 2), rng.uniform(-math.pi, math.pi))
        self.t_cam = rng.uniform(-0.3, 0.3, 3) + [0, 0, 0.8]
        self.t_prism = rng.uniform(-0.3, 0.3, 3) + [0, 0, 1.2]
        self.base_T_camera = make_T(self.R_bc, self.t_cam)
        self.C = self.p + self.R @ self.t_cam
        self.P = self.p + self.R @ self.t_prism
        d = rng.normal(size=(n_markers, 3))
        d[:, 2] *= 0.3                      # markers mostly around the horizon
        d /= np.linalg.norm(d, axis=1)[:, None]
        near = max(1.0, 2.0 * float(np.linalg.norm(self.t_cam - self.t_prism)) + 0.1)
        self.M = self.C + d * rng.uniform(near, 20.0, (n_markers, 1))

    @property
    def mounting(self):
        return Mounting(self.base_T_camera, self.t_prism)

    def bearings(self, M=None, sigma=0.0):
        """Camera-frame unit bearings of markers M (default: the scene's), with isotropic noise σ (rad)."""
        M = self.M if M is None else M
        u = ((M - self.C) @ self.R) @ self.R_bc
        u /= np.linalg.norm(u, axis=1)[:, None]
        if sigma:
            u = np.array([perturb(x, sigma, self.rng) for x in u])
        return u


def perturb(u, sigma, rng):
    """Unit vector u turned by a 2-D isotropic normal angle of σ (rad) per perpendicular axis."""
    a = np.array([1.0, 0, 0]) if abs(u[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    v = u + sigma * (rng.normal() * e1 + rng.normal() * e2)
    return v / np.linalg.norm(v)


# ----------------------------------------------------------------------------- yaw_from_marker


@given(seeds, tilts, tilts, yaws)
def test_yaw_exact_any_quadrant(seed, roll, pitch, yaw):
    s = Scene(seed, roll, pitch, yaw, 1)
    est = yaw_from_marker(s.bearings()[0], s.M[0], s.P, (roll, pitch), s.mounting)
    assert abs(wrap_angle(est.yaw - yaw)) < 1e-9
    assert est.range == pytest.approx(np.linalg.norm(s.M[0] - s.C), abs=1e-9)
    np.testing.assert_allclose(est.camera_position, s.C, atol=1e-9)
    assert abs(est.elevation_residual) < 1e-9


@pytest.mark.parametrize("yaw_deg", [-180.0, -135.0, -90.0, -45.0, 0.0, 45.0, 90.0, 135.0, 179.999])
def test_yaw_unique_in_every_quadrant_with_a_long_lever_arm(yaw_deg):
    """The paper's cosine solution has 4 candidates; the closed form returns the true one."""
    s = Scene(7, 0.03, -0.02, math.radians(yaw_deg), 1)
    s.t_cam = np.array([0.6, -0.4, 0.5])           # long lever arm: 0.7 m vs a 1.5 m marker
    s.base_T_camera = make_T(s.R_bc, s.t_cam)
    s.C = s.p + s.R @ s.t_cam
    s.M = s.C + np.array([[1.2, 0.9, 0.1]])
    est = yaw_from_marker(s.bearings()[0], s.M[0], s.P, (s.roll, s.pitch), s.mounting)
    assert abs(wrap_angle(est.yaw - s.yaw)) < 1e-9


def test_yaw_sigma_matches_monte_carlo():
    """All five noise sources at once: normalised yaw errors have std 1 ± 20 %."""
    s = Scene(3, 0.05, -0.04, 2.5, 1)
    sb, sp, sm, st_, sl = 2e-3, 0.01, 0.005, 2e-3, 0.01
    rng = np.random.default_rng(11)
    u0 = s.bearings()[0]
    errs, sig = [], []
    for _ in range(1500):
        u = perturb(u0, sb, rng)
        P = s.P + sp * rng.normal(size=3)
        M = s.M[0] + sm * rng.normal(size=3)
        r, p = s.roll + st_ * rng.normal(), s.pitch + st_ * rng.normal()
        t_cam = s.t_cam + sl * rng.normal(size=3)
        est = yaw_from_marker(u, M, P, (r, p), Mounting(make_T(s.R_bc, t_cam), s.t_prism),
                              NoiseModel(bearing=sb, prism_cov=sp * sp * np.eye(3), marker=sm, tilt=st_, lever=sl))
        errs.append(wrap_angle(est.yaw - s.yaw))
        sig.append(est.sigma)
    z = np.array(errs) / np.array(sig)
    assert 0.8 < np.std(z) < 1.2
    assert abs(np.mean(z)) < 0.15
    # The range matters: a 2 mm survey error on a 5 m marker should not look like a 20 m one.
    assert 1e-4 < np.median(sig) < 0.05


def test_yaw_jacobian_matches_finite_differences():
    """σ² for each noise source alone equals the squared finite-difference sensitivity."""
    s = Scene(5, 0.1, 0.05, -1.0, 1)
    u = s.bearings()[0]
    base = yaw_from_marker(u, s.M[0], s.P, (s.roll, s.pitch), s.mounting).yaw
    h = 1e-6
    for axis in range(3):
        dP = np.zeros(3)
        dP[axis] = h
        fd = (yaw_from_marker(u, s.M[0], s.P + dP, (s.roll, s.pitch), s.mounting).yaw
              - yaw_from_marker(u, s.M[0], s.P - dP, (s.roll, s.pitch), s.mounting).yaw) / (2 * h)
        cov = np.zeros((3, 3))
        cov[axis, axis] = 1.0
        sig = yaw_from_marker(u, s.M[0], s.P, (s.roll, s.pitch), s.mounting, NoiseModel(prism_cov=cov)).sigma
        assert sig == pytest.approx(abs(fd), rel=1e-5, abs=1e-9)
    fd_roll = (yaw_from_marker(u, s.M[0], s.P, (s.roll + h, s.pitch), s.mounting).yaw
               - yaw_from_marker(u, s.M[0], s.P, (s.roll - h, s.pitch), s.mounting).yaw) / (2 * h)
    fd_pitch = (yaw_from_marker(u, s.M[0], s.P, (s.roll, s.pitch + h), s.mounting).yaw
                - yaw_from_marker(u, s.M[0], s.P, (s.roll, s.pitch - h), s.mounting).yaw) / (2 * h)
    sig = yaw_from_marker(u, s.M[0], s.P, (s.roll, s.pitch), s.mounting, NoiseModel(tilt=1.0)).sigma
    assert sig == pytest.approx(math.hypot(fd_roll, fd_pitch), rel=1e-5)
    assert abs(base - s.yaw) < 1e-9


def test_false_id_shows_in_the_elevation_residual():
    """A marker id swapped for one 1.5 m higher: the elevation check is far outside its σ."""
    s = Scene(9, 0.0, 0.0, 0.4, 1)
    u = s.bearings()[0]
    wrong = s.M[0] + [0.0, 0.0, 1.5]
    est = yaw_from_marker(u, wrong, s.P, (0.0, 0.0), s.mounting,
                          NoiseModel(bearing=1e-3, prism_cov=0.005, marker=0.002))
    assert abs(est.elevation_residual) > 10 * est.elevation_sigma


def test_yaw_degenerate_geometry_is_reported():
    s = Scene(1, 0.0, 0.0, 0.0, 1)
    u = s.bearings()[0]
    lever = np.linalg.norm(s.t_cam - s.t_prism)
    near = s.P + np.array([0.5 * lever, 0.0, 0.0])          # marker inside the lever-arm sphere
    with pytest.raises(DegenerateGeometryError, match="lever arm"):
        yaw_from_marker(u, near, s.P, (0.0, 0.0), s.mounting)
    above = s.P + np.array([0.0, 0.0, 5.0])                 # straight above the prism
    with pytest.raises(DegenerateGeometryError, match="vertical"):
        yaw_from_marker(u, above, s.P, (0.0, 0.0), s.mounting)
    with pytest.raises(SolverError, match="prism"):
        yaw_from_marker(u, s.M[0], [np.nan, 0, 0], (0.0, 0.0), s.mounting)
    with pytest.raises(SolverError, match="tilt"):
        yaw_from_marker(u, s.M[0], s.P, (np.nan, 0.0), s.mounting)
    with pytest.raises(SolverError, match="tilt"):
        three = Scene(2, 0.0, 0.0, 0.0, 3)
        attitude_from_markers(three.bearings(), three.M, three.P, three.mounting, tilt=(0.0,))


def test_fused_frame_yaw_is_honest_where_independent_fusion_is_not():
    """Four markers on one side share one prism (2 cm) and tilt error: their yaw errors are correlated.
    GLS with the shared covariance stays honest; inverse-variance fusion as if independent does not."""
    s = Scene(17, 0.03, 0.02, -0.7, 4)
    az = np.radians([10.0, 25.0, 40.0, 55.0])
    s.M = s.C + np.stack([np.cos(az), np.sin(az), [0.1, -0.05, 0.2, 0.0]], axis=1) * [[3.0], [4.0], [5.0], [3.5]]
    sb, sp, st_ = 1e-3, 0.02, 1e-3
    z_gls, z_naive = [], []
    for _ in range(400):
        P = s.P + sp * s.rng.normal(size=3)
        r, p = s.roll + st_ * s.rng.normal(), s.pitch + st_ * s.rng.normal()
        u = s.bearings(sigma=sb)
        est = [yaw_from_marker(u[i], s.M[i], P, (r, p), s.mounting,
                               NoiseModel(bearing=sb, prism_cov=sp, tilt=st_)) for i in range(4)]
        fused = fuse_yaws(est)
        z_gls.append(wrap_angle(fused.yaw - s.yaw) / fused.sigma)
        w = np.array([1 / e.sigma ** 2 for e in est])
        naive = np.sum(w * np.array([e.yaw for e in est])) / w.sum()
        z_naive.append(wrap_angle(naive - s.yaw) * math.sqrt(w.sum()))
    assert 0.8 < np.std(z_gls) < 1.2
    assert np.std(z_naive) > 1.3


def test_fuse_yaws_drops_a_false_id():
    s = Scene(18, 0.0, 0.0, 3.0, 5)
    u = s.bearings(sigma=5e-4)
    M = s.M.copy()
    M[1] = s.M[1] + [2.0, 1.0, 0.0]
    est = [yaw_from_marker(u[i], M[i], s.P, (0.0, 0.0), s.mounting,
                           NoiseModel(bearing=5e-4, prism_cov=0.005)) for i in range(5)]
    fused = fuse_yaws(est)
    np.testing.assert_array_equal(fused.used, [True, False, True, True, True])
    assert abs(wrap_angle(fused.yaw - s.yaw)) < 4 * fused.sigma
    with pytest.raises(SolverError):
        fuse_yaws([])


# ----------------------------------------------------------------------------- attitude


@given(seeds, tilts, tilts, yaws, st.integers(2, 6))
def test_attitude_exact(seed, roll, pitch, yaw, n):
    s = Scene(seed, roll, pitch, yaw, n)
    d = (s.M - s.C) / np.linalg.norm(s.M - s.C, axis=1)[:, None]
    assume(np.linalg.norm(np.cross(d[:, None], d[None]), axis=-1).max() > math.sin(math.radians(6)))
    est = attitude_from_markers(s.bearings(), s.M, s.P, s.mounting, noise=NoiseModel(bearing=1e-3, prism_cov=0.005),
                                tilt=(0.0, 0.0))
    np.testing.assert_allclose(est.R, s.R, atol=1e-9)
    assert abs(wrap_angle(est.yaw - yaw)) < 1e-9
    np.testing.assert_allclose(est.prism, s.P, atol=1e-9)
    assert np.all(est.residuals < 1e-9) and np.all(est.weights == 1.0)


def test_attitude_covariance_is_honest():
    s = Scene(21, 0.04, -0.06, -2.8, 3)
    sb, sp = 1.5e-3, 0.01
    z = []
    for _ in range(200):
        P = s.P + sp * s.rng.normal(size=3)
        est = attitude_from_markers(s.bearings(sigma=sb), s.M, P, s.mounting,
                                    noise=NoiseModel(bearing=sb, prism_cov=sp))   # default: robust, then gated LS
        err = wrap_angle(np.array([est.roll - s.roll, est.pitch - s.pitch, est.yaw - s.yaw]))
        z.append(err / np.sqrt(np.diag(est.cov)))
    sd = np.std(np.array(z), axis=0)
    assert np.all((sd > 0.8) & (sd < 1.2)), sd


def test_attitude_rejects_a_false_marker_id():
    s = Scene(4, 0.02, 0.01, 1.0, 5)
    u = s.bearings(sigma=1e-3)
    M = s.M.copy()
    M[2] = s.M[2] + [3.0, -2.0, 0.5]           # the map position of another id
    clean = attitude_from_markers(u[[0, 1, 3, 4]], s.M[[0, 1, 3, 4]], s.P, s.mounting)
    plain = attitude_from_markers(u, M, s.P, s.mounting, settings=FitSettings(loss="none"))
    for loss in ("cauchy", "huber"):
        robust = attitude_from_markers(u, M, s.P, s.mounting, settings=FitSettings(loss=loss))
        np.testing.assert_array_equal(robust.weights, [1, 1, 0, 1, 1])
        assert robust.normalized[2] > 20
        # The gated least-squares stage is the clean solution on the four true markers.
        np.testing.assert_allclose(robust.R, clean.R, atol=1e-12)
        np.testing.assert_allclose(robust.cov, clean.cov, rtol=1e-6)
        assert abs(wrap_angle(plain.yaw - s.yaw)) > 5 * abs(wrap_angle(robust.yaw - s.yaw))
    robust_only = attitude_from_markers(u, M, s.P, s.mounting,
                                        settings=FitSettings(outlier_gate=None))
    assert 0 < robust_only.weights[2] < 0.01


def test_attitude_degenerate_when_markers_in_one_direction():
    s = Scene(2, 0.0, 0.0, 0.3, 1)
    d = (s.M[0] - s.C) / np.linalg.norm(s.M[0] - s.C)
    M = np.array([s.C + 3.0 * d, s.C + 9.0 * d, s.C - 4.0 * d])   # behind and in front, one line
    with pytest.raises(DegenerateGeometryError, match="one line"):
        attitude_from_markers(s.bearings(M), M, s.P, s.mounting)
    with pytest.raises(SolverError, match="≥ 2"):
        attitude_from_markers(s.bearings()[:1], s.M[:1], s.P, s.mounting)


# ----------------------------------------------------------------------------- resection


@given(seeds, tilts, tilts, yaws, st.integers(4, 7))
def test_resection_exact(seed, roll, pitch, yaw, n):
    s = Scene(seed, roll, pitch, yaw, n)
    sv = np.linalg.svd(s.M - s.M.mean(axis=0), compute_uv=False)
    assume(sv[1] > 0.1 * sv[0])            # not (nearly) collinear: that case is tested below
    est = resection(s.bearings(), s.M, s.base_T_camera, tilt=(roll, pitch))
    np.testing.assert_allclose(est.R, s.R, atol=1e-9)
    np.testing.assert_allclose(est.position, s.p, atol=1e-9)
    np.testing.assert_allclose(est.map_T_base, make_T(s.R, s.p), atol=1e-9)


def test_resection_three_markers_with_level_start():
    s = Scene(8, 0.03, -0.02, 2.0, 3)
    est = resection(s.bearings(), s.M, s.base_T_camera)
    np.testing.assert_allclose(est.position, s.p, atol=1e-9)
    assert abs(wrap_angle(est.yaw - s.yaw)) < 1e-9


def test_resection_covariance_is_honest():
    s = Scene(13, 0.02, 0.03, -1.2, 5)
    sb = 1e-3
    z = []
    for _ in range(250):
        est = resection(s.bearings(sigma=sb), s.M, s.base_T_camera, noise=NoiseModel(bearing=sb),
                        tilt=(s.roll, s.pitch), settings=FitSettings(loss="none"))
        err = np.concatenate([est.position - s.p,
                              wrap_angle(np.array(matrix_to_rpy(est.R)) - [s.roll, s.pitch, s.yaw])])
        z.append(err / np.sqrt(np.diag(est.cov)))
    sd = np.std(np.array(z), axis=0)
    assert np.all((sd > 0.8) & (sd < 1.2)), sd


def test_resection_collinear_markers_are_degenerate():
    s = Scene(6, 0.0, 0.0, 0.0, 1)
    M = s.C + np.array([[4.0, 1.0, 0.5], [5.0, 2.0, 0.5], [6.0, 3.0, 0.5], [8.0, 5.0, 0.5]])
    with pytest.raises(DegenerateGeometryError, match="collinear"):
        resection(s.bearings(M), M, s.base_T_camera)


def test_tilt_rotation_order_matches_transforms():
    """R_t = Ry(pitch)·Rx(roll) is the tilt part of rpy_to_matrix (guards the convention used above)."""
    r, p, y = 0.1, -0.2, 0.7
    np.testing.assert_allclose(rpy_to_matrix(r, p, y), rpy_to_matrix(0, 0, y) @ rot_y(p) @ rot_x(r), atol=1e-15)


@given(seeds, tilts, tilts, yaws, st.integers(2, 5))
def test_resection_with_a_known_tilt_is_exact_from_two_markers(seed, roll, pitch, yaw, n):
    """The tilt as a measurement (IMU, odometry): 2 markers determine position and yaw, up to a discrete
    ambiguity (two markers with a known vertical can have two solutions): from a start pose near the truth
    (the filter's prediction) the right one. Where the two solutions lie closer together than the start's error
    (a fold of the two-marker geometry: seed 509080389, 8 cm and 0.22° apart) either may come out, and the
    covariance says so (yaw σ of hundreds of degrees): never a wrong pose with a small σ."""
    s = Scene(seed, roll, pitch, yaw, n)
    dirs = s.M - s.C
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    assume(float(np.max(np.linalg.norm(np.cross(dirs[:, None], dirs[None]), axis=-1))) > math.sin(math.radians(15)))
    start = make_T(rpy_to_matrix(roll, pitch, yaw + 0.02), s.p + s.rng.normal(0.0, 0.05, 3))  # a filter prediction
    est = resection(s.bearings(), s.M, s.base_T_camera, tilt=(roll, pitch), tilt_sigma=math.radians(0.1),
                    initial_pose=start)
    assert est.cov.shape == (6, 6) and np.all(np.linalg.eigvalsh(est.cov) > 0)
    sd = np.sqrt(np.diag(est.cov))
    if sd[5] < math.radians(1.0):  # determined: the right solution, exactly
        np.testing.assert_allclose(est.position, s.p, atol=1e-6)
        assert abs(wrap_angle(est.yaw - yaw)) < 1e-7
    else:  # a fold: the σ covers whichever solution came out
        assert abs(wrap_angle(est.yaw - yaw)) < 3.0 * sd[5]
        assert np.all(np.abs(est.position - s.p) < 3.0 * sd[:3] + 1e-6)


@pytest.mark.parametrize("seed,n", [(509080389, 2), (12345, 2)])
def test_two_markers_with_a_known_tilt_either_exact_or_saying_they_are_undetermined(seed, n):
    """The fold found by the property above, and a plain two-marker case: the first with a yaw σ > 1°, the second
    exact with a yaw σ < 1°."""
    s = Scene(seed, 0.0547, -0.0921, -2.884, n)
    start = make_T(rpy_to_matrix(0.0547, -0.0921, -2.884 + 0.02), s.p + s.rng.normal(0.0, 0.05, 3))
    est = resection(s.bearings(), s.M, s.base_T_camera, tilt=(0.0547, -0.0921), tilt_sigma=math.radians(0.1),
                    initial_pose=start)
    sd_yaw = math.sqrt(est.cov[5, 5])
    exact = np.allclose(est.position, s.p, atol=1e-6) and abs(wrap_angle(est.yaw + 2.884)) < 1e-7
    assert exact or sd_yaw > math.radians(1.0), (est.position - s.p, sd_yaw)
    assert (sd_yaw > math.radians(1.0)) == (seed == 509080389)


def test_resection_with_a_wrong_tilt_measurement_and_three_markers_follows_the_markers():
    """A tilt measured 2° off with σ 2°: ≥ 3 well-spread markers outweigh it."""
    s = Scene(5, 0.05, -0.03, 1.0, 6)
    est = resection(s.bearings(), s.M, s.base_T_camera, tilt=(0.05 + math.radians(2), -0.03),
                    tilt_sigma=math.radians(2.0), noise=NoiseModel(bearing=1e-4))
    assert abs(est.roll - 0.05) < math.radians(0.05)
    assert abs(wrap_angle(est.yaw - 1.0)) < math.radians(0.05)


def test_resection_refuses_markers_in_one_small_cone_or_along_one_line_through_the_camera():
    s = Scene(3, 0.0, 0.0, 0.3, 3)
    ahead = s.C + np.array([[10.0, 0.0, 0.0], [10.0, 0.8, 0.3], [10.0, -0.5, 0.6]])   # within ~6° of each other
    with pytest.raises(DegenerateGeometryError, match="cone"):
        resection(s.bearings(ahead), ahead, s.base_T_camera, tilt=(0.0, 0.0), tilt_sigma=0.01)
    both = s.C + np.array([[6.0, 1.0, 0.2], [-12.0, -2.0, -0.4]])          # opposite: one line through the camera
    with pytest.raises(DegenerateGeometryError, match="collinear|singular"):
        resection(s.bearings(both), both, s.base_T_camera, tilt=(0.0, 0.0), tilt_sigma=0.01)
    with pytest.raises(SolverError, match="≥ 3"):
        resection(s.bearings()[:2], s.M[:2], s.base_T_camera)
