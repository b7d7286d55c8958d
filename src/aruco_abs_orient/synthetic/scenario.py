"""A deterministic synthetic scenario: the hidden truth every test and the demo check against.

A platform (``base_link``) drives a smooth closed loop in ``map`` after standing still for a
few seconds, mostly level (roll/pitch of a degree or two from the ground). Around the loop hang
ArUco markers at surveyed positions, each facing the track. The platform carries a 360° camera
(lever arm ``base_link → camera`` with a small boresight error that is rendered but not
published) and a prism tracked by a total station (~19 Hz, mm noise, jittered stamps, dropouts).
Visual odometry ``odom → base_link`` drifts: its yaw error grows linearly plus a random walk,
its translation integrates the true motion through that yaw error with a scale error, plus
jitter. The camera/VO clock runs ``camera_time_offset`` seconds ahead of true time.

The realistic world and the camera effects (all off in the easy world's presets):
``world="hall"`` puts the loop in an interior (walls, floor, ceiling with lights, pillars that
hide markers, posters and checker patterns; synthetic/world.py); the platform wanders
sideways (``lateral_wander``, m) and its heading follows its path (non-holonomic), with a roll/
pitch wobble (``tilt_wobble_deg``); the VO also drifts in tilt (``vo_tilt_drift_deg_per_min``).
A platform may crab (``crab_deg``: base_link x off its direction of travel); a VO without gravity
keeps odom at base_link's starting pose, tilt included (``odom_levelled=False``); the marker map
written is the survey, each position off the truth by ``survey_noise`` m per axis.

The camera is two back-to-back fisheye lenses (``camera.DualFisheye``): each lens's centre
``lens_offset`` m from the camera origin along its axis (camera ±x, seams at ±90° azimuth), the
back lens turned by ``lens_rotation_deg`` about a random axis relative to the front, the two images
stitched at ``stitch_distance`` m and blended over ``blend_band_deg`` at the seams; every pixel is
rendered along its lens's ray (:attr:`Scenario.lenses`), and :meth:`Scenario.marker_bearings` gives
the stitched bearings.

Rolling shutter (``rolling_shutter_readout`` = R seconds from the first to the last row): the
frame's stamp is the capture time of its middle row, and image row v (0 = top, H rows) is
captured at ``stamp + (v / H − ½) · R`` (:meth:`Scenario.row_times`); the same convention is
written into hidden.yaml. Camera clock rate error (``clock_rate_error_ppm`` = ε·10⁶): the camera
takes a frame every 1/fps seconds of ITS clock, which runs at (1 + ε) times true time, so
``stamp = t + camera_time_offset + ε · (t − start_time)`` (:meth:`Scenario.camera_clock`).

Everything follows from a ``ScenarioConfig`` (its ``seed`` included; the parameters and the presets are
synthetic/config.py's, re-exported here), so a scenario is rebuilt exactly from the hidden-parameters YAML
(:meth:`Scenario.from_hidden`).

Units: metres, seconds (absolute ROS times, ``start_time`` + offset), radians inside the code;
the config's angles are in degrees where the field name says ``_deg``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, List, Tuple

import numpy as np

from ..camera import DualFisheye
from ..markers import Marker, MarkerMap, square_corners, upright_rotation
from ..transforms import invert_T, make_T, matrix_to_rpy, rot_z, rpy_to_matrix, transform_points
from ..tum import atomic_write_text, read_yaml
from .config import PRESETS, ScenarioConfig, ScenarioError
from .render import PROFILES, PlacedMarker, facing_marker
from .world import Hall

__all__ = ["ScenarioError", "ScenarioConfig", "PRESETS", "Scenario", "PrismTrack"]

_DT = 0.002  # s, integration grid of the motion and of the VO
_TAIL = 5.0  # s of motion computed beyond the duration (late stamps, offsets)


@dataclass(frozen=True)
class PrismTrack:
    """Total-station samples: ``stamps`` (N,) true times in s, ``positions`` (N, 3) prism in map, m."""

    stamps: np.ndarray
    positions: np.ndarray


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


class Scenario:
    """The truth of one scenario. Times are absolute true times in seconds; all functions of
    time are vectorised (scalar t → single pose (4, 4), array (N,) → (N, 4, 4))."""

    def __init__(self, config: ScenarioConfig):
        self.config = config.validate()
        c = config
        rng = np.random.default_rng([c.seed, 1])
        self._loop_motion(rng)
        # --- the realistic world (its own random stream: the easy world's draws stay as they were)
        rng_real = np.random.default_rng([c.seed, 17])
        self._wander_phase = rng_real.uniform(0.0, 2.0 * math.pi, 2)
        self._wobble_phase = rng_real.uniform(0.0, 2.0 * math.pi, 4)
        tilt_az = rng_real.uniform(-math.pi, math.pi)
        self.vo_tilt_axis = np.array([math.cos(tilt_az), math.sin(tilt_az), 0.0])
        self.exposure_phase = rng_real.uniform(0.0, 2.0 * math.pi, 2)
        # --- the two lenses and the crab (their own random stream: the other draws stay as they were)
        rng_lens = np.random.default_rng([c.seed, 28])
        lens_axis = rng_lens.normal(size=3)
        self.lens_rotation = math.radians(c.lens_rotation_deg) * lens_axis / np.linalg.norm(lens_axis)
        self.lenses = DualFisheye(c.lens_offset, self.lens_rotation, c.stitch_distance, math.radians(c.blend_band_deg))
        self._crab_phase = float(rng_lens.uniform(0.0, 2.0 * math.pi))
        # --- lever arms and the boresight error (a rotation of boresight_deg about a random axis)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        self.boresight_axis = axis
        self.base_T_camera_nominal = make_T(np.eye(3), c.camera_lever_arm)
        self.base_T_camera_true = make_T(_axis_angle(axis, math.radians(c.boresight_deg)), c.camera_lever_arm)
        self.base_T_prism = make_T(np.eye(3), c.prism_lever_arm)
        # --- markers around the track, facing it (± a random yaw/tilt), and the survey of them
        self.markers, self.marker_normals = self._place_markers(rng)
        self.surveyed_markers = self._survey(np.random.default_rng([c.seed, 29]))
        self._visual_odometry(rng)
        # --- total station samples (true time stamps), with jitter, dropouts and gaps
        self.prism = self._prism_track(rng)
        # --- the interior around it all (walls, pillars, posters, lights), or None: the easy world's panorama
        self.world = Hall(self, np.random.default_rng([c.seed, 18])) if c.world == "hall" else None
        if any(c.moved_marker):  # a knocked marker: the truth moves, its survey and the world stay as they were
            m = self.markers[self.markers.ids[0]]
            self.markers.markers[m.id] = m._replace(position=m.position + np.asarray(c.moved_marker))

    def _loop_motion(self, rng) -> None:
        """The motion along the loop: θ(t) on the grid ``_tg`` integrated so that |dP/dt| follows the speed
        profile, from ``_theta0`` (drawn from ``rng``, then the roll/pitch phases ``_rp_phase``)."""
        c = self.config
        n = int(math.ceil((c.duration + _TAIL) / _DT)) + 1
        self._tg = np.arange(n) * _DT
        speed = (c.speed * _smoothstep((self._tg - c.standstill) / c.accel_time)).tolist()
        self._theta0 = float(rng.uniform(-math.pi, math.pi))
        self._rp_phase = rng.uniform(0.0, 2.0 * math.pi, 4)
        a, b = c.track_radii
        theta = [self._theta0]
        th = self._theta0
        for k in range(n - 1):  # midpoint rule; dθ/dt = v / |P'(θ)|
            mid = th + 0.5 * _DT * speed[k] / math.hypot(a * math.sin(th), b * math.cos(th))
            th += _DT * 0.5 * (speed[k] + speed[k + 1]) / math.hypot(a * math.sin(mid), b * math.cos(mid))
            theta.append(th)
        self._theta = np.array(theta)

    def _visual_odometry(self, rng) -> None:
        """The visual odometry's errors (drawn from ``rng``): yaw error = drift·t + random walk, translation
        jitter; its position integrates the motion through them (``_vo_pos`` on the grid ``_tg``)."""
        c = self.config
        walk_dt = 0.1
        walk_n = int(math.ceil((c.duration + _TAIL) / walk_dt)) + 2
        steps = rng.normal(0.0, math.radians(c.vo_yaw_walk_deg_per_sqrt_s) * math.sqrt(walk_dt), walk_n)
        steps[0] = 0.0
        self._walk_t = np.arange(walk_n) * walk_dt
        self._walk = np.cumsum(steps)
        jitter_dt = 0.02
        jitter_n = int(math.ceil((c.duration + _TAIL) / jitter_dt)) + 2
        self._jitter_t = np.arange(jitter_n) * jitter_dt
        self._jitter = rng.normal(0.0, c.vo_translation_noise, (jitter_n, 3))
        self._jitter -= self._jitter[0]
        p = self._path_point(self._theta)
        psi0 = float(self._path_yaw(self._theta0) + self._crab(self._theta0))
        yaw_err = self.vo_yaw_error(self._tg + c.start_time)
        mid_err = 0.5 * (yaw_err[1:] + yaw_err[:-1])
        dp = np.diff(p, axis=0)
        self._psi0 = psi0
        # odom: levelled, at base_link's starting heading; or base_link's starting pose, tilt included
        self._odom_R_map0 = None if c.odom_levelled else self.map_T_base(c.start_time)[:3, :3].T
        if self._odom_R_map0 is None:
            steps_o = (rot_z(mid_err - psi0) @ dp[:, :, None])[:, :, 0] * (1.0 + c.vo_scale_error)
        else:
            steps_o = (self._odom_R_map0 @ rot_z(mid_err) @ dp[:, :, None])[:, :, 0] * (1.0 + c.vo_scale_error)
        self._vo_pos = np.concatenate([np.zeros((1, 3)), np.cumsum(steps_o, axis=0)])

    # ---- construction helpers --------------------------------------------------------------
    def _track_point(self, theta) -> np.ndarray:
        """Point(s) P(θ) (…, 3) of the loop in map, m (ground height undulates by ±2 cm)."""
        a, b = self.config.track_radii
        cx, cy = self.config.track_center
        theta = np.asarray(theta, dtype=float)
        return np.stack([cx + a * np.cos(theta), cy + b * np.sin(theta), 0.02 * np.sin(3.0 * theta)], axis=-1)

    def _yaw_on_track(self, theta):
        a, b = self.config.track_radii
        return np.arctan2(b * np.cos(theta), -a * np.sin(theta))  # counter-clockwise travel

    # lateral wander: cycles per loop of its two components and their share of the amplitude
    _WANDER = ((13.0, 0.6), (29.0, 0.4))

    def _path_point(self, theta) -> np.ndarray:
        """Where base_link drives: the loop P(θ) moved sideways by the wander (±lateral_wander m,
        along the loop's left normal), m."""
        p = self._track_point(theta)
        amp = self.config.lateral_wander
        if amp == 0.0:
            return p
        theta = np.asarray(theta, dtype=float)
        w = amp * sum(share * np.sin(k * theta + ph) for (k, share), ph in zip(self._WANDER, self._wander_phase))
        yaw = self._yaw_on_track(theta)
        return p + np.stack([-np.sin(yaw) * w, np.cos(yaw) * w, np.zeros_like(w)], axis=-1)

    def _path_yaw(self, theta):
        """Heading of base_link at θ: the direction of its path (a non-holonomic platform)."""
        if self.config.lateral_wander == 0.0:
            return self._yaw_on_track(theta)
        h = 1e-5
        d = self._path_point(np.asarray(theta, dtype=float) + h) - self._path_point(np.asarray(theta, dtype=float) - h)
        return np.arctan2(d[..., 1], d[..., 0])

    def _crab(self, theta):
        """How far base_link's heading is off its direction of travel at θ (radians): 0.7 of ``crab_deg``
        constant, 0.3 swinging twice a loop (a skid-steer platform, a holonomic one side-stepping)."""
        if self.config.crab_deg == 0.0:
            return 0.0
        return math.radians(self.config.crab_deg) * (0.7 + 0.3 * np.sin(2.0 * np.asarray(theta) + self._crab_phase))

    def _survey(self, rng) -> MarkerMap:
        """The marker map as surveyed: each true position off by ``survey_noise`` m per axis (σ written as the
        marker's survey σ; 2 mm when exact)."""
        noise = self.config.survey_noise
        out = [Marker(m.id, m.position + rng.normal(0.0, noise, 3), m.size, noise or m.sigma) for m in self.markers]
        return MarkerMap(out, self.markers.dictionary, self.markers.frame_id, source="synthetic scenario's survey")

    def _roll_pitch(self, theta):
        amp = math.radians(self.config.roll_pitch_deg)
        ph = self._rp_phase
        roll = amp * (0.7 * np.sin(3.0 * theta + ph[0]) + 0.3 * np.sin(7.0 * theta + ph[1]))
        pitch = amp * (0.7 * np.sin(2.0 * theta + ph[2]) + 0.3 * np.sin(5.0 * theta + ph[3]))
        wobble = math.radians(self.config.tilt_wobble_deg)
        if wobble > 0.0:  # bumps of ~0.7-1.3 m wavelength on a loop of ~50 m
            wp = self._wobble_phase
            roll = roll + wobble * (0.6 * np.sin(41.0 * theta + wp[0]) + 0.4 * np.sin(67.0 * theta + wp[1]))
            pitch = pitch + wobble * (0.6 * np.sin(37.0 * theta + wp[2]) + 0.4 * np.sin(73.0 * theta + wp[3]))
        return roll, pitch

    def _place_markers(self, rng) -> Tuple[MarkerMap, Dict[int, np.ndarray]]:
        c = self.config
        dmin, dmax = c.marker_distance
        dense = self._track_point(np.linspace(-math.pi, math.pi, 720, endpoint=False))
        lo = dense[:, :2].min(axis=0) - dmax
        hi = dense[:, :2].max(axis=0) + dmax
        ids = sorted(rng.choice(_dictionary_size(c.dictionary), size=c.n_markers, replace=False).tolist())
        markers: List[Marker] = []
        normals: Dict[int, np.ndarray] = {}
        centres: List[np.ndarray] = []
        start = self._track_point(self._theta0)[:2]
        near_start = max(dmin + 1.0, 0.6 * dmax)
        for i, marker_id in enumerate(rng.permutation(ids).tolist()):
            for _ in range(10000):
                xy = rng.uniform(lo, hi)
                d = np.linalg.norm(dense[:, :2] - xy, axis=1)
                k = int(np.argmin(d))
                if not dmin <= d[k] <= dmax:
                    continue
                if i < 2 and np.linalg.norm(xy - start) > near_start:
                    continue  # two markers in view at the start (standstill initialisation)
                centre = np.array([xy[0], xy[1], rng.uniform(*c.marker_height)])
                if any(np.linalg.norm(centre - o) < max(1.0, 5 * c.marker_size) for o in centres):
                    continue
                break
            else:
                raise ScenarioError(f"marker_distance: cannot place {c.n_markers} markers "
                                    f"{dmin}-{dmax} m from the track")
            # outside the loop face its centre (seen from most of the loop), inside the nearest track point
            (cx, cy), (ra, rb) = c.track_center, c.track_radii
            outside = ((xy[0] - cx) / ra) ** 2 + ((xy[1] - cy) / rb) ** 2 > 1.0
            towards = (np.array([cx, cy]) if outside else dense[k, :2]) - xy
            yaw = math.atan2(towards[1], towards[0]) + rng.uniform(-0.35, 0.35)
            tilt = rng.uniform(-0.15, 0.15)
            normal = np.array([math.cos(yaw) * math.cos(tilt), math.sin(yaw) * math.cos(tilt), math.sin(tilt)])
            centres.append(centre)
            normals[marker_id] = normal
            markers.append(Marker(marker_id, centre, c.marker_size, 0.002))
        if c.spin_markers:
            taken = {m.id for m in markers}
            self._place_spin_markers(np.random.default_rng([c.seed, 19]), taken, markers, normals)
        markers.sort(key=lambda m: m.id)
        return MarkerMap(markers, c.dictionary, "map", source="synthetic scenario"), normals

    def _place_spin_markers(self, rng, taken: set, markers: List[Marker], normals: Dict[int, np.ndarray]) -> None:
        """``spin_markers`` markers around the start for a calibration spin, beside the track (left and right
        in turn, 70° and 110° off its direction, then 50° and 130°), 1.8-2.6 m from base_link, two low (0.2 m)
        then two high (2.6 m), each facing the camera: markers far above and below the horizon let the rolling
        shutter's readout show."""
        c = self.config
        start = self._path_point(self._theta0)
        heading = float(self._path_yaw(self._theta0))
        eye = start + np.array([0.0, 0.0, c.camera_lever_arm[2]])
        free = [i for i in range(_dictionary_size(c.dictionary)) if i not in taken]
        for k, marker_id in enumerate(sorted(rng.choice(free, size=c.spin_markers, replace=False).tolist())):
            side = 1.0 if k % 2 == 0 else -1.0
            az = heading + side * math.radians((70.0, 110.0, 50.0, 130.0)[k // 2] + rng.uniform(-5.0, 5.0))
            r = rng.uniform(1.8, 2.6)
            centre = start + np.array([r * math.cos(az), r * math.sin(az), 0.0])
            centre[2] = 0.2 if (k // 2) % 2 == 0 else 2.6
            normal = (eye - centre) / np.linalg.norm(eye - centre)
            normals[marker_id] = normal
            markers.append(Marker(marker_id, centre, c.marker_size, 0.002))

    def _prism_track(self, rng) -> PrismTrack:
        c = self.config
        period = 1.0 / c.prism_rate
        span = c.duration + abs(c.camera_time_offset) + 1.0
        n = int(span * c.prism_rate)
        t = c.start_time - 0.5 + np.arange(n) * period + rng.uniform(-c.prism_jitter, c.prism_jitter, n)
        keep = rng.random(n) >= c.prism_dropout
        t_moving = c.start_time + c.standstill + c.accel_time
        for _ in range(c.prism_gaps):
            if c.start_time + c.duration - t_moving > 2.0:
                g0 = rng.uniform(t_moving, c.start_time + c.duration - 1.5)
                keep &= ~((t >= g0) & (t < g0 + rng.uniform(0.6, 1.4)))
        o0, od = c.prism_outage
        keep &= ~((t >= c.start_time + o0) & (t < c.start_time + o0 + od))
        t = t[keep]
        pos = self.prism_position(t) + rng.normal(0.0, c.prism_noise, (t.size, 3))
        return PrismTrack(t, pos)

    # ---- truth -----------------------------------------------------------------------------
    @property
    def frame_times(self) -> np.ndarray:
        """True capture times (N,) of the camera frames (of their middle rows), s: one every 1/fps
        seconds of the camera's clock, which runs clock_rate_error_ppm fast."""
        c = self.config
        return c.start_time + np.arange(int(round(c.duration * c.fps))) / c.fps / (1.0 + 1e-6 * c.clock_rate_error_ppm)

    @property
    def camera_stamps(self) -> np.ndarray:
        """Camera/VO clock stamps (N,) of the frames, s (:meth:`camera_clock` of their true times)."""
        return self.camera_clock(self.frame_times)

    def camera_clock(self, t):
        """The camera/VO clock's reading at true time(s) t: t + camera_time_offset + ε · (t − start_time),
        ε = clock_rate_error_ppm · 1e-6."""
        c = self.config
        t = np.asarray(t, dtype=float)
        return t + c.camera_time_offset + 1e-6 * c.clock_rate_error_ppm * (t - c.start_time)

    def true_time(self, stamp):
        """The true time(s) at which the camera/VO clock reads ``stamp`` (s): :meth:`camera_clock` inverted."""
        c = self.config
        eps = 1e-6 * c.clock_rate_error_ppm
        return (np.asarray(stamp, dtype=float) - c.camera_time_offset + eps * c.start_time) / (1.0 + eps)

    def row_times(self, t: float, height: int) -> np.ndarray:
        """True capture times (height,) of the image rows of the frame whose middle row is captured at
        true time t: row v at t + (v / height − ½) · rolling_shutter_readout (all t without a rolling
        shutter)."""
        return float(t) + (np.arange(int(height)) / float(height) - 0.5) * self.config.rolling_shutter_readout

    def exposure_gain(self, t):
        """The camera's exposure (brightness factor, 1 ± exposure_wander) at true time(s) t: two slow
        oscillations, as an auto-exposure hunting under changing light."""
        c = self.config
        tr = np.asarray(t, dtype=float) - c.start_time
        ph = self.exposure_phase
        return 1.0 + c.exposure_wander * (0.6 * np.sin(2 * math.pi * 0.07 * tr + ph[0])
                                          + 0.4 * np.sin(2 * math.pi * 0.23 * tr + ph[1]))

    def _theta_at(self, t):
        return np.interp(np.asarray(t, dtype=float) - self.config.start_time, self._tg, self._theta)

    def map_T_base(self, t) -> np.ndarray:
        """True pose(s) of base_link in map at true time(s) t."""
        theta = self._theta_at(t)
        roll, pitch = self._roll_pitch(theta)
        yaw = self._path_yaw(theta) + self._spin(t) + self._crab(theta)
        return make_T(rpy_to_matrix(roll, pitch, yaw), self._path_point(theta))

    def _spin(self, t):
        """Yaw turned in place so far at true time(s) t (radians; 0 without ``spin_deg``)."""
        c = self.config
        if c.spin_deg == 0.0:
            return 0.0
        x = (np.asarray(t, dtype=float) - c.start_time - c.spin_start) / c.spin_time
        return math.radians(c.spin_deg) * _smoothstep(x)

    def vo_yaw_error(self, t):
        """VO yaw error (radians) at true time(s) t: linear drift + random walk, 0 at start_time."""
        tr = np.asarray(t, dtype=float) - self.config.start_time
        rate = math.radians(self.config.vo_yaw_drift_deg_per_min) / 60.0
        return rate * tr + np.interp(tr, self._walk_t, self._walk)

    def vo_tilt_error(self, t):
        """VO tilt error (radians, about the horizontal ``vo_tilt_axis``) at true time(s) t: linear drift."""
        tr = np.asarray(t, dtype=float) - self.config.start_time
        return math.radians(self.config.vo_tilt_drift_deg_per_min) / 60.0 * tr

    def imu_samples(self) -> Tuple[np.ndarray, np.ndarray]:
        """The IMU's samples: true times (N,) s and (roll, pitch) (N, 2) of base_link in rad with
        ``imu_tilt_noise_deg`` noise (empty without an IMU; its own random stream)."""
        c = self.config
        if c.imu_rate <= 0:
            return np.zeros(0), np.zeros((0, 2))
        rng = np.random.default_rng([c.seed, 2])
        t = c.start_time - 0.5 + np.arange(int((c.duration + 1.0) * c.imu_rate)) / c.imu_rate
        rp = np.stack(matrix_to_rpy(self.map_T_base(t)[:, :3, :3])[:2], axis=-1)
        return t, rp + rng.normal(0.0, math.radians(c.imu_tilt_noise_deg), rp.shape)

    def odom_T_base(self, t) -> np.ndarray:
        """The VO's pose(s) of base_link in odom at true time(s) t (what /tf carries, stamped
        t + camera_time_offset). odom is the base_link pose at start_time, levelled (or, with
        ``odom_levelled`` false, tilted as base_link was); its roll and pitch
        drift by :meth:`vo_tilt_error`."""
        tr = np.asarray(t, dtype=float) - self.config.start_time
        if self._odom_R_map0 is None:
            R = rot_z(self.vo_yaw_error(t) - self._psi0) @ self.map_T_base(t)[..., :3, :3]
        else:
            R = self._odom_R_map0 @ rot_z(self.vo_yaw_error(t)) @ self.map_T_base(t)[..., :3, :3]
        if self.config.vo_tilt_drift_deg_per_min != 0.0:
            R = _axis_angle(self.vo_tilt_axis, self.vo_tilt_error(t)) @ R
        pos = np.stack([np.interp(tr, self._tg, self._vo_pos[:, k]) for k in range(3)], axis=-1)
        pos = pos + np.stack([np.interp(tr, self._jitter_t, self._jitter[:, k]) for k in range(3)], axis=-1)
        return make_T(R, pos)

    def map_T_odom(self, t) -> np.ndarray:
        """The correct map → odom at true time(s) t (what the package should estimate)."""
        return self.map_T_base(t) @ invert_T(self.odom_T_base(t))

    def map_T_camera(self, t) -> np.ndarray:
        """True camera pose(s) in map (boresight error included)."""
        return self.map_T_base(t) @ self.base_T_camera_true

    def prism_position(self, t) -> np.ndarray:
        """Noise-free prism position(s) (…, 3) in map at true time(s) t, m."""
        T = self.map_T_base(t)
        return T[..., :3, :3] @ np.asarray(self.config.prism_lever_arm) + T[..., :3, 3]

    def map_R_marker(self, marker_id: int) -> np.ndarray:
        """Orientation of a marker's face in map (z = the hidden normal, y up the face)."""
        return upright_rotation(self.marker_normals[marker_id])

    def placed_markers(self, t: float) -> List[PlacedMarker]:
        """The markers in the true camera frame at true time t, for the renderer (with the
        impostor in the frames :meth:`has_impostor` picks)."""
        camera_T_map = invert_T(self.map_T_camera(float(t)))
        out = []
        for m in self.markers:
            centre = transform_points(camera_T_map, m.position)
            R = camera_T_map[:3, :3] @ self.map_R_marker(m.id)
            out.append(PlacedMarker(m.id, m.size, centre, R))
        impostor = self.impostor(t)
        return out + ([impostor] if impostor is not None else [])

    def impostor(self, t: float):
        """The false-id impostor (a PlacedMarker in the camera frame) in the frames :meth:`has_impostor`
        picks, else None."""
        if not self.has_impostor(t):
            return None
        first = self.markers.ids[0]
        return facing_marker(first, self.markers[first].size, np.array([2.8, 2.8, 0.3]))

    def marker_bearings(self, t, max_range: float = 12.0, max_incidence_deg: float = 80.0, noise: float = 0.0,
                        rng=None) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact bearings of the markers the true camera sees at true times ``t`` (N,), without rendering:
        those within ``max_range`` m whose face is turned less than ``max_incidence_deg`` from the camera.

        Returns (frame index into ``t`` (K,), marker ids (K,), unit bearings (K, 3) in the true camera
        frame, boresight error included, where the stitched image shows the marker's centre: the lenses'
        parallax and rotations included, a marker across a seam by its corners' diagonals), each bearing
        perturbed by ``noise`` rad per axis (``rng``: a numpy Generator). For tests and benchmarks of the
        geometry that detection would only slow down."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        T = self.map_T_camera(t)                                                   # (N, 4, 4)
        M = np.array([m.position for m in self.markers])                           # (J, 3)
        normals = np.array([self.marker_normals[m.id] for m in self.markers])      # (J, 3)
        ids = np.array([m.id for m in self.markers])
        d = M[None, :, :] - T[:, None, :3, 3]                                      # camera → marker, map
        r = np.linalg.norm(d, axis=2)
        facing = -np.einsum("njk,jk->nj", d, normals) / r                          # cos(incidence)
        seen = (r < max_range) & (facing > math.cos(math.radians(max_incidence_deg)))
        frame, j = np.nonzero(seen)
        q = np.einsum("nki,nk->ni", T[frame, :3, :3], d[frame, j])
        if self.lenses.single_centre:
            u = self.lenses.project(q)
        else:      # where a detector finds the centre: the diagonals of the corners, each through its lens
            K = np.array([square_corners(m.size, n) for m, n in zip(self.markers, normals)]).reshape(-1, 4, 3)
            corners = np.einsum("nki,nck->nci", T[frame, :3, :3], d[frame, j][:, None, :] + K[j])
            u = self.lenses.project_marker(q, corners)
        if noise > 0:
            u = u + (rng or np.random.default_rng()).normal(0.0, noise, u.shape)
            u /= np.linalg.norm(u, axis=1, keepdims=True)
        return frame, ids[j], u

    def has_impostor(self, t: float) -> bool:
        """Whether the frame at true time t shows the false-id impostor (seeded, per frame)."""
        rate = self.config.impostor_rate
        if rate <= 0.0:
            return False
        return bool(np.random.default_rng([self.config.seed, 7919, int(round(float(t) * 1e3))]).random() < rate)

    def camera_yaw(self, t):
        """Yaw (radians) of the true camera in map at true time(s) t (rolls the background)."""
        return matrix_to_rpy(self.map_T_camera(t)[..., :3, :3])[2]

    # ---- hidden parameters -----------------------------------------------------------------
    def hidden(self) -> dict:
        """Everything needed to rebuild the scenario (``config``) plus derived truth for readers."""
        c = self.config
        return {
            "format": "aruco_abs_orient synthetic scenario 1",
            "config": c.to_dict(),
            "camera_time_offset": c.camera_time_offset,
            "boresight": {"angle_deg": c.boresight_deg, "axis": [round(float(x), 9) for x in self.boresight_axis],
                          "rpy_deg": [round(math.degrees(float(a)), 9)
                                      for a in matrix_to_rpy(self.base_T_camera_true[:3, :3])]},
            "base_T_camera_true": _rows(self.base_T_camera_true),
            "base_T_camera_nominal": _rows(self.base_T_camera_nominal),
            "base_T_prism": _rows(self.base_T_prism),
            "vo_drift": {"yaw_drift_deg_per_min": c.vo_yaw_drift_deg_per_min,
                         "yaw_walk_deg_per_sqrt_s": c.vo_yaw_walk_deg_per_sqrt_s,
                         "scale_error": c.vo_scale_error, "translation_noise_m": c.vo_translation_noise,
                         "yaw_error_at_end_deg": round(math.degrees(float(
                             self.vo_yaw_error(c.start_time + c.duration))), 6)},
            "map_T_odom_at_start": _rows(self.map_T_odom(c.start_time)),
            "marker_normals": {int(k): [round(float(x), 9) for x in v] for k, v in self.marker_normals.items()},
            "marker_positions": {int(m.id): [round(float(x), 9) for x in m.position] for m in self.markers},
            "prism_samples": int(self.prism.stamps.size),
            "realism": self._hidden_realism(),
        }

    def _hidden_realism(self) -> dict:
        """The parameters of the realistic world's effects (those of the easy world are zero / absent)."""
        c = self.config
        out = {
            "world": c.world,
            "rolling_shutter": {
                "readout_s": c.rolling_shutter_readout,
                "convention": "the image stamp is the capture time of the middle row; row v (0 = top) of H "
                              "is captured at stamp + (v / H - 1/2) * readout_s"},
            "camera_clock": {"rate_error_ppm": c.clock_rate_error_ppm,
                             "convention": "stamp = t + camera_time_offset + rate_error_ppm * 1e-6 * (t - start_time); "
                                           "a frame every 1/fps s of the camera clock"},
            "platform": {"lateral_wander_m": c.lateral_wander, "crab_deg": c.crab_deg,
                         "crab_convention": "base_link yaw = direction of travel + crab_deg * (0.7 + 0.3 sin(2 theta "
                                            "+ crab_phase)), theta the loop parameter",
                         "crab_phase_rad": round(self._crab_phase, 9),
                         "wander_cycles_per_loop_and_share": [list(w) for w in self._WANDER],
                         "wander_phase_rad": [round(float(x), 9) for x in self._wander_phase],
                         "tilt_wobble_deg": c.tilt_wobble_deg,
                         "wobble_phase_rad": [round(float(x), 9) for x in self._wobble_phase]},
            "vo_tilt": {"drift_deg_per_min": c.vo_tilt_drift_deg_per_min,
                        "axis_in_map": [round(float(x), 9) for x in self.vo_tilt_axis]},
            "exposure": {"time_s": c.exposure_time, "wander": c.exposure_wander,
                         "frequencies_hz": [0.07, 0.23], "shares": [0.6, 0.4],
                         "phase_rad": [round(float(x), 9) for x in self.exposure_phase],
                         "motion_blur": "horizontal box of |camera yaw rate| * time_s, centred on each row's time"},
            "jpeg_quality": c.jpeg_quality or PROFILES[c.profile].jpeg_quality,
            "camera_lenses": {
                "lens_offset_m": c.lens_offset, "stitch_distance_m": c.stitch_distance,
                "blend_band_deg": c.blend_band_deg,
                "back_lens_rotation_deg": [round(math.degrees(float(x)), 9) for x in self.lens_rotation],
                "convention": "two fisheye lenses along camera +x (front) and -x (back), centres at +-lens_offset_m "
                              "on their axes; the back lens turned by back_lens_rotation_deg (a rotation vector) "
                              "relative to the front, each by half of it (front -1/2, back +1/2); stitched at "
                              "stitch_distance_m, the front lens's weight rising linearly across blend_band_deg at "
                              "azimuths +-90 deg"},
            "odom_levelled": c.odom_levelled,
            "survey_noise_m": c.survey_noise,
        }
        if self.world is not None:
            out["hall"] = self.world.hidden()
        return out

    def save_hidden(self, path: str) -> None:
        """Write :meth:`hidden` as YAML, atomically."""
        import yaml

        text = ("# Hidden truth of a synthetic scenario (aruco_abs_orient.synthetic). Scenario.from_hidden()\n"
                "# rebuilds it from 'config'; the rest is derived, for readers. Angles in degrees where named.\n")
        atomic_write_text(path, text + yaml.safe_dump(self.hidden(), sort_keys=False, default_flow_style=None))

    @classmethod
    def from_hidden(cls, path: str) -> Scenario:
        """Rebuild the scenario from a hidden-parameters YAML written by the generator."""
        data = read_yaml(path, ScenarioError)
        if not isinstance(data, dict) or "config" not in data:
            raise ScenarioError(f"{path}: no 'config' mapping: not a hidden-parameters file")
        scenario = cls(ScenarioConfig.from_dict(data["config"], source=f"{path}: config"))
        normals = data.get("marker_normals", {})
        for k, v in normals.items():
            if int(k) not in scenario.marker_normals or not np.allclose(v, scenario.marker_normals[int(k)],
                                                                         atol=1e-6):
                raise ScenarioError(f"{path}: marker_normals[{k}] does not match the rebuilt scenario "
                                    "(written by another version of the generator?)")
        return scenario


def _axis_angle(axis, angle) -> np.ndarray:
    """Rotation matrix (3, 3), or (N, 3, 3) for angles (N,), of ``angle`` radians about unit ``axis``
    (Rodrigues)."""
    k = np.asarray(axis, dtype=float)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    a = np.asarray(angle, dtype=float)[..., None, None]
    return np.eye(3) + np.sin(a) * K + (1.0 - np.cos(a)) * (K @ K)


def _rows(T) -> list:
    return [[round(float(x), 12) for x in row] for row in np.asarray(T)]


def _dictionary_size(dictionary: str) -> int:
    import cv2

    return int(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)).bytesList.shape[0])

