"""The parameters of a synthetic scenario and its named presets.

In: keyword values for :class:`ScenarioConfig` (every parameter of a scenario, the hidden truth included: the
motion, the markers, the lever arms, the VO's drift, the total station, the realistic world's and the camera's
effects; angles in degrees where the name ends in ``_deg``, else metres, seconds, Hz), or a mapping
(:meth:`ScenarioConfig.from_dict`, the ``config`` of a hidden-parameters YAML). Out: a frozen, validated
config (:meth:`ScenarioConfig.validate` raises :class:`ScenarioError` naming the field), and :data:`PRESETS`,
the named configs the generator, the tests and the benches start from (``tiny``, ``ci``, ``easy``, ``demo``,
``realistic`` …). What a config makes is ``scenario.Scenario``'s.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Dict, Tuple

from ..errors import ConfigurationError
from ..markers import ARUCO_DICTIONARIES
from .render import PROFILES
from .world import WORLDS

__all__ = ["ScenarioError", "ScenarioConfig", "PRESETS", "REALISTIC"]


class ScenarioError(ConfigurationError):
    """An invalid scenario parameter or hidden-parameters file (the message names the field)."""


@dataclass(frozen=True)
class ScenarioConfig:
    """Every parameter of a scenario (hidden truth included). Angles in degrees where the
    name ends in ``_deg``; metres, seconds, Hz otherwise."""

    seed: int = 0
    duration: float = 20.0  # s of images
    fps: float = 15.0  # camera frame rate, Hz
    width: int = 1920  # equirect image width, px (height = width / 2)
    profile: str = "realistic"  # render profile (render.PROFILES)
    dictionary: str = "DICT_4X4_50"
    start_time: float = 1_700_000_000.0  # true time of the first image, s (ROS time)
    standstill: float = 3.0  # s at rest before driving
    spin_deg: float = 0.0  # whole turns in place during the standstill, from 1 s in (a calibration manoeuvre)
    spin_rate_deg_per_s: float = 60.0  # the spin's peak turn rate (it lasts 1.5 · spin_deg / rate s)
    spin_markers: int = 0  # more markers 1.8-2.6 m around the start, two 0.2 m high then two 2.6 m, facing it
    speed: float = 0.8  # cruise speed, m/s
    accel_time: float = 2.0  # s from rest to cruise speed
    track_radii: Tuple[float, float] = (9.0, 6.0)  # loop semi-axes, m
    track_center: Tuple[float, float] = (6.0, 3.0)  # loop centre in map, m
    roll_pitch_deg: float = 1.5  # amplitude of ground-induced roll/pitch, deg
    n_markers: int = 6
    marker_size: float = 0.19  # black square side, m
    marker_distance: Tuple[float, float] = (2.0, 12.0)  # marker centre to nearest track point, m
    marker_height: Tuple[float, float] = (0.5, 2.5)  # marker centre above the map origin, m
    camera_lever_arm: Tuple[float, float, float] = (0.10, 0.0, 0.80)  # base_link → camera, m
    prism_lever_arm: Tuple[float, float, float] = (-0.25, 0.05, 1.10)  # base_link → prism, m
    boresight_deg: float = 0.3  # angle of the unpublished camera rotation error, deg
    camera_time_offset: float = 0.367  # camera/VO stamp − true time, s
    vo_yaw_drift_deg_per_min: float = 4.0  # linear VO yaw drift, deg/min
    vo_yaw_walk_deg_per_sqrt_s: float = 0.03  # VO yaw random walk, deg/√s
    vo_scale_error: float = 0.005  # relative VO translation scale error
    vo_translation_noise: float = 0.003  # VO position jitter σ, m
    prism_rate: float = 19.0  # total-station rate, Hz
    prism_jitter: float = 0.004  # stamp jitter (uniform ±), s
    prism_noise: float = 0.002  # prism position σ per axis, m
    prism_dropout: float = 0.02  # probability of losing one prism sample
    prism_gaps: int = 2  # number of ~1 s tracking losses (while driving)
    prism_outage: Tuple[float, float] = (0.0, 0.0)  # (start after start_time, duration) of a prism dropout, s
    imu_rate: float = 0.0  # IMU (roll, pitch) rate, Hz (0: no IMU)
    imu_tilt_noise_deg: float = 0.02  # IMU roll/pitch noise σ, deg
    impostor_rate: float = 0.0  # fraction of frames showing a false id: a second marker with the
    # id of the map's first marker, 4 m ahead-left of the camera (not where the map has it)
    # --- the realistic world and the camera effects; the defaults are the easy world
    world: str = "open"  # "open": a textured panorama; "hall": an interior (synthetic/world.py)
    lateral_wander: float = 0.0  # amplitude of the platform's sideways wander off the loop, m
    tilt_wobble_deg: float = 0.0  # amplitude of a short-wavelength roll/pitch wobble, deg
    vo_tilt_drift_deg_per_min: float = 0.0  # VO tilt error growth about a random horizontal axis
    exposure_time: float = 0.0  # s; motion blur along the camera's yaw rotation (0 = none)
    exposure_wander: float = 0.0  # relative amplitude of exposure and per-surface brightness changes
    jpeg_quality: int = 0  # 1-100; 0 = the render profile's
    rolling_shutter_readout: float = 0.0  # s from the first to the last image row (0 = global)
    lens_offset: float = 0.0  # m, each fisheye lens's centre from the camera origin along its axis (0: one centre)
    lens_rotation_deg: float = 0.0  # the back lens's rotation relative to the front, about a random axis, deg
    stitch_distance: float = math.inf  # m, the scene distance the two images are stitched at
    blend_band_deg: float = 2.0  # width of the blend band at each seam, deg
    crab_deg: float = 0.0  # base_link heading off the direction of travel: 0.7 of it constant, 0.3 swinging
    odom_levelled: bool = True  # False: odom is base_link's starting pose, roll and pitch too (a VO without gravity)
    survey_noise: float = 0.0  # m per axis: the written marker map's positions off the true ones
    clock_rate_error_ppm: float = 0.0  # camera clock rate (frame rate) error, parts per million
    moved_marker: Tuple[float, float, float] = (0.0, 0.0, 0.0)  # m: the lowest id moved by this since its survey

    def validate(self) -> ScenarioConfig:
        """Check ranges; raises ScenarioError naming the field. Returns self."""
        def need(ok: bool, name: str, what: str):
            if not ok:
                raise ScenarioError(f"{name}: {what}, got {getattr(self, name)!r}")

        need(isinstance(self.seed, int) and self.seed >= 0, "seed", "expected a non-negative integer")
        need(self.duration > 0 and math.isfinite(self.duration), "duration", "expected seconds > 0")
        need(0 < self.fps <= 120, "fps", "expected 0 < fps <= 120")
        need(isinstance(self.width, int) and self.width >= 64 and self.width % 2 == 0, "width",
             "expected an even number of pixels >= 64")
        need(self.profile in PROFILES, "profile", f"expected one of {', '.join(PROFILES)}")
        need(self.dictionary in ARUCO_DICTIONARIES, "dictionary", "expected a cv2.aruco dictionary name")
        need(self.standstill >= 0, "standstill", "expected seconds >= 0")
        need(0 < self.spin_rate_deg_per_s <= 180, "spin_rate_deg_per_s", "expected deg/s in (0, 180]")
        need(isinstance(self.spin_markers, int) and 0 <= self.spin_markers <= 8, "spin_markers",
             "expected an integer in [0, 8]")
        need(self.spin_deg % 360.0 == 0.0, "spin_deg", "expected whole turns (a multiple of 360°: the platform "
             "drives off forwards)")
        need(self.spin_deg == 0.0 or self.standstill >= self.spin_start + self.spin_time, "spin_deg",
             f"a spin of {self.spin_deg:g}° at {self.spin_rate_deg_per_s:g}°/s takes {self.spin_time:.1f} s: "
             f"expected a standstill of at least {self.spin_start + self.spin_time:.1f} s")
        need(self.speed >= 0 and self.accel_time > 0, "speed", "expected speed >= 0 and accel_time > 0")
        need(min(self.track_radii) > 0.5, "track_radii", "expected semi-axes > 0.5 m")
        need(self.n_markers >= 1, "n_markers", "expected at least one marker")
        need(0 < self.marker_size < 5, "marker_size", "expected metres in (0, 5)")
        need(0 < self.marker_distance[0] < self.marker_distance[1], "marker_distance", "expected 0 < min < max")
        need(self.marker_height[0] <= self.marker_height[1], "marker_height", "expected min <= max")
        need(0 <= self.boresight_deg < 10, "boresight_deg", "expected degrees in [0, 10)")
        need(abs(self.camera_time_offset) < 10, "camera_time_offset", "expected |offset| < 10 s")
        need(0 < self.prism_rate <= 100, "prism_rate", "expected Hz in (0, 100]")
        need(0 <= self.prism_dropout < 1, "prism_dropout", "expected a probability in [0, 1)")
        need(0 <= self.impostor_rate <= 1, "impostor_rate", "expected a fraction in [0, 1]")
        need(self.prism_outage[1] >= 0, "prism_outage", "expected (start s, duration s >= 0)")
        need(0 <= self.imu_rate <= 1000 and self.imu_tilt_noise_deg >= 0, "imu_rate",
             "expected Hz in [0, 1000] and imu_tilt_noise_deg >= 0")
        need(self.prism_jitter < 0.5 / self.prism_rate, "prism_jitter", "expected less than half a period")
        for name in ("prism_noise", "vo_translation_noise", "vo_yaw_walk_deg_per_sqrt_s", "prism_gaps"):
            need(getattr(self, name) >= 0, name, "expected >= 0")
        need(self.world in WORLDS, "world", f"expected one of {', '.join(WORLDS)}")
        need(0 <= self.lateral_wander <= 0.5, "lateral_wander", "expected metres in [0, 0.5]")
        need(0 <= self.tilt_wobble_deg <= 5, "tilt_wobble_deg", "expected degrees in [0, 5]")
        need(abs(self.vo_tilt_drift_deg_per_min) <= 10, "vo_tilt_drift_deg_per_min", "expected |deg/min| <= 10")
        need(0 <= self.exposure_time <= 0.1, "exposure_time", "expected seconds in [0, 0.1]")
        need(0 <= self.exposure_wander < 0.5, "exposure_wander", "expected a fraction in [0, 0.5)")
        need(0 <= self.jpeg_quality <= 100, "jpeg_quality", "expected 1-100, or 0 for the profile's")
        need(0 <= self.rolling_shutter_readout <= 0.04, "rolling_shutter_readout",
             "expected a readout time in [0, 0.04] s")
        need(0 <= self.lens_offset <= 0.05, "lens_offset", "expected metres in [0, 0.05]")
        need(0 <= self.lens_rotation_deg <= 2, "lens_rotation_deg", "expected degrees in [0, 2]")
        need(self.stitch_distance >= 1.0, "stitch_distance", "expected metres >= 1, or inf")
        need(0 < self.blend_band_deg <= 20, "blend_band_deg", "expected degrees in (0, 20]")
        need(abs(self.crab_deg) <= 10, "crab_deg", "expected |degrees| <= 10")
        need(0 <= self.survey_noise <= 0.05, "survey_noise", "expected metres in [0, 0.05]")
        need(abs(self.clock_rate_error_ppm) <= 1000, "clock_rate_error_ppm", "expected |ppm| <= 1000")
        need(all(abs(x) <= 1 for x in self.moved_marker), "moved_marker", "expected metres within ±1 per axis")
        return self

    #: s from the start to the spin in place (when spin_deg is not 0)
    spin_start = 1.0

    @property
    def spin_time(self) -> float:
        """Duration of the spin in place, s (0 without one): a smoothstep of peak rate spin_rate_deg_per_s."""
        return 1.5 * abs(self.spin_deg) / self.spin_rate_deg_per_s

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict, source: str = "<memory>") -> ScenarioConfig:
        """A config from a mapping (e.g. the ``config`` of a hidden YAML); unknown keys are errors."""
        if not isinstance(data, dict):
            raise ScenarioError(f"{source}: expected a mapping of scenario parameters")
        fields = {f.name: f for f in dataclasses.fields(cls)}
        kwargs = {}
        for key, value in data.items():
            if key not in fields:
                raise ScenarioError(f"{source}: unknown scenario parameter {key!r}")
            default = fields[key].default
            if isinstance(default, tuple):
                if not isinstance(value, (list, tuple)) or len(value) != len(default):
                    raise ScenarioError(f"{source}: {key}: expected a list of {len(default)} numbers")
                value = tuple(float(x) for x in value)
            elif isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
            elif type(value) is not type(default):
                raise ScenarioError(f"{source}: {key}: expected {type(default).__name__}, got {value!r}")
            kwargs[key] = value
        try:
            return cls(**kwargs).validate()
        except ScenarioError as e:
            raise ScenarioError(f"{source}: {e}") from None


REALISTIC = ScenarioConfig(
    duration=60.0, fps=30.0, width=3840, n_markers=10, marker_size=0.19, marker_distance=(2.0, 12.0),
    profile="hall", world="hall", lateral_wander=0.01, tilt_wobble_deg=0.3, vo_tilt_drift_deg_per_min=0.5,
    exposure_time=0.006, exposure_wander=0.15, jpeg_quality=85, clock_rate_error_ppm=20.0, lens_offset=0.01,
    lens_rotation_deg=0.05, blend_band_deg=2.0, survey_noise=0.002, odom_levelled=False)

PRESETS: Dict[str, ScenarioConfig] = {
    # plumbing tests: big markers so they are visible at 960 px
    "tiny": ScenarioConfig(duration=8.0, fps=10.0, width=960, standstill=2.0, n_markers=5, marker_size=0.45,
                           marker_distance=(2.0, 6.0), track_radii=(5.0, 3.5)),
    "ci": ScenarioConfig(duration=20.0, fps=15.0, width=1920, n_markers=8, marker_size=0.30,
                         marker_distance=(2.0, 8.0)),
    # the paper's set-up: 19 cm DICT_4X4 markers at 2-12 m, Theta Z1 frames at 30 fps, in the easy world
    "easy": ScenarioConfig(duration=60.0, fps=30.0, width=3840, n_markers=10, marker_size=0.19,
                           marker_distance=(2.0, 12.0)),
    # the same in the realistic world: the hall, a wandering platform, a VO drifting in yaw and
    # tilt, exposure changes, motion blur, JPEG 85, a stitch seam, a camera clock 20 ppm fast, and a 30 ms
    # rolling shutter (bench/realism.py: the pipeline initialises and keeps its heading on it uncorrected)
    "demo": dataclasses.replace(REALISTIC, rolling_shutter_readout=0.030),
    # markers only (no total station): a smaller loop with 12 markers, >= 3 in view nearly everywhere
    "markers_only": ScenarioConfig(duration=15.0, fps=10.0, width=1920, n_markers=12, marker_size=0.30,
                                   marker_distance=(2.0, 7.0), track_radii=(6.0, 4.0), standstill=2.0,
                                   boresight_deg=0.0),
    "bench": ScenarioConfig(duration=10.0, fps=30.0, width=3840, n_markers=10, marker_size=0.19,
                            marker_distance=(2.0, 12.0)),
    "realistic": dataclasses.replace(REALISTIC, duration=20.0),
    # the realistic world with a 30 ms rolling shutter
    "realistic-rs": dataclasses.replace(REALISTIC, duration=20.0, rolling_shutter_readout=0.030),
    # a calibration run in that world: a 360° spin in place at up to 60°/s beside 4 markers 0.2 and 2.6 m high,
    # 2 m away (the rolling shutter's readout shows in a fast turn across elevations), then 19 s of the drive
    "calibration-rs": dataclasses.replace(REALISTIC, duration=30.0, standstill=11.0, spin_deg=360.0,
                                          spin_markers=4, rolling_shutter_readout=0.030),
    # the scenario tests' realistic world: ci's size (1920 px, 15 fps, 30 cm markers at 2-8 m, 20 s) in the
    # demo's world with its 30 ms rolling shutter (rendered in ~10 s on 2 cores)
    "ci-realistic": dataclasses.replace(REALISTIC, duration=20.0, fps=15.0, width=1920, n_markers=8,
                                        marker_size=0.30, marker_distance=(2.0, 8.0), rolling_shutter_readout=0.030),
}
