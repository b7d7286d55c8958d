"""The realistic world of the synthetic scenarios and the frame renderer of both worlds.

:class:`Hall` is an interior around the scenario's loop: a box room (floor with tiles, walls with
panels, a ceiling with bright light panels), floor-to-ceiling pillars (some placed on the line
between the track and a marker, so they hide markers), and posters on the walls: checker patterns
and block posters whose dark rectangles are quad candidates for a marker detector, none of them
an ArUco code. Every surface (and every marker) has its own brightness, which changes slowly over
time; the camera's exposure wanders as well.

:func:`render_frame` renders a scenario's frame: the easy world ("open") through
:func:`render.render_equirect` unchanged when no camera effect is on; otherwise ray casting in
``map`` with one camera pose per image row (a rolling shutter: row v of H at the frame's true time
+ (v/H − ½)·readout, :meth:`Scenario.row_times`). The room is shaded at an eighth of the
resolution and scaled up (it is smooth); posters and markers are shaded at full resolution with
the renderer's supersampling and a depth buffer, pillars at full resolution with anti-aliased
edges and the depth test. Every ray starts at the centre of the lens the stitched pixel comes from
and runs along that lens's direction (the scenario's ``lenses``, a ``camera.DualFisheye``; markers and
posters blend both lenses across the seams' band, the room and the pillars take the lens with the
larger share). Then the camera: exposure, a horizontal motion blur of the camera's yaw rate × exposure
time, sensor noise, optical blur (render.finish_frame).

Units: metres, seconds, radians; grey levels 0-255 (values above 255 saturate).
"""

from __future__ import annotations

import functools
import math
from typing import List, Optional, Tuple

import cv2
import numpy as np

from ..camera import DualFisheye, Equirect, bearing_to_azel
from ..markers import upright_rotation
from ..transforms import invert_T
from . import render
from .render import PlacedMarker, finish_frame

__all__ = ["WORLDS", "Hall", "render_frame"]

WORLDS = ("open", "hall")

_LOW_RES = 8  # the room is shaded at 1/_LOW_RES of the resolution
_FLOOR_Z = -0.15  # m, below base_link's ground contact
_CEILING_Z = 4.2  # m
_MARGIN = 2.0  # m between the outermost marker or track point and a wall
_TILE = 0.6  # m, floor tiles
_PANEL = 1.2  # m, wall panels
_PILLAR_ROW_STEP = 4  # pillars are shaded on every 4th row and interpolated
_LIGHT_STEP = 4.0  # m between ceiling light panels
_LIGHT_HALF = (0.6, 0.15)  # m, half length and half width of a light panel
_INK, _PAPER = 18.0, 235.0  # grey levels of a printed marker's black and white under unit light


class _Light:
    """A slowly changing brightness: gain0 · (1 + amp · sin(2π f t + phase))."""

    def __init__(self, rng, gain0: float, amp: float):
        self.gain0 = float(gain0)
        self.amp = float(amp)
        self.freq = float(rng.uniform(0.03, 0.2))
        self.phase = float(rng.uniform(0.0, 2.0 * math.pi))

    def __call__(self, t: float) -> float:
        return self.gain0 * (1.0 + self.amp * math.sin(2.0 * math.pi * self.freq * t + self.phase))

    def hidden(self) -> dict:
        return {"gain": round(self.gain0, 6), "amplitude": round(self.amp, 6), "freq_hz": round(self.freq, 6),
                "phase_rad": round(self.phase, 6)}


class Hall:
    """The interior around a scenario's track and markers (built from its own random generator).

    ``bounds`` ((2, 3) m: min and max corner of the room), ``pillars`` (K, 3): x, y, radius in m,
    ``posters``: list of (kind, centre (3,), map_R_face (3, 3), side m, texture (n, n) float32),
    ``lights`` (L, 4): x0, y0, x1, y1 of the ceiling panels, ``surface_light``: per surface
    (floor, ceiling, walls, pillars, posters) a brightness over time, ``marker_light``: per marker id.
    """

    def __init__(self, scenario, rng):
        c = scenario.config
        self.start_time = c.start_time
        wander = c.exposure_wander
        path = scenario._path_point(np.linspace(-math.pi, math.pi, 720, endpoint=False))
        marker_pos = np.array([m.position for m in scenario.markers])
        xy = np.concatenate([path[:, :2], marker_pos[:, :2]])
        lo, hi = xy.min(axis=0) - _MARGIN, xy.max(axis=0) + _MARGIN
        self.bounds = np.array([[lo[0], lo[1], _FLOOR_Z], [hi[0], hi[1], _CEILING_Z]])
        self.pillars = self._place_pillars(rng, path, marker_pos)
        self.posters = self._place_posters(rng)
        # ceiling light panels (2 × _LIGHT_HALF m) on a square grid of _LIGHT_STEP m from lo + step/2
        self._light_origin = lo + _LIGHT_STEP / 2
        gx = np.arange(lo[0] + _LIGHT_STEP / 2, hi[0], _LIGHT_STEP)
        gy = np.arange(lo[1] + _LIGHT_STEP / 2, hi[1], _LIGHT_STEP)
        hx, hy = _LIGHT_HALF
        self.lights = np.array([[x - hx, y - hy, x + hx, y + hy] for x in gx for y in gy])
        self.surface_light = {name: _Light(rng, rng.uniform(0.8, 1.1), wander * rng.uniform(0.3, 1.0))
                              for name in ("floor", "ceiling", "wall_x", "wall_y", "pillars", "posters")}
        self.marker_light = {int(m.id): _Light(rng, rng.uniform(0.7, 1.05), wander * rng.uniform(0.3, 1.0))
                             for m in scenario.markers}

    # ---- construction --------------------------------------------------------------------------
    def _place_pillars(self, rng, path, marker_pos) -> np.ndarray:
        pillars: List[Tuple[float, float, float]] = []
        for _ in range(2000):
            if len(pillars) == 8:
                break
            a = path[rng.integers(path.shape[0]), :2]
            b = marker_pos[rng.integers(marker_pos.shape[0]), :2]
            p = a + rng.uniform(0.35, 0.75) * (b - a)  # on a line of sight from the track to a marker
            r = rng.uniform(0.12, 0.3)
            if np.min(np.linalg.norm(path[:, :2] - p, axis=1)) < r + 0.8:
                continue
            if np.min(np.linalg.norm(marker_pos[:, :2] - p, axis=1)) < r + 0.6:
                continue
            if any(math.hypot(p[0] - q[0], p[1] - q[1]) < 1.5 for q in pillars):
                continue
            pillars.append((float(p[0]), float(p[1]), float(r)))
        return np.array(pillars).reshape(-1, 3)

    def _place_posters(self, rng) -> list:
        (x0, y0, _), (x1, y1, _) = self.bounds
        walls = [((x0, None), np.array([1.0, 0.0, 0.0])), ((x1, None), np.array([-1.0, 0.0, 0.0])),
                 ((None, y0), np.array([0.0, 1.0, 0.0])), ((None, y1), np.array([0.0, -1.0, 0.0]))]
        posters = []
        for i in range(14):
            (wx, wy), normal = walls[i % 4]
            side = float(rng.uniform(0.4, 1.2))
            z = float(rng.uniform(0.9, 3.2))
            if wx is not None:
                centre = np.array([wx + 0.01 * normal[0], rng.uniform(y0 + 1, y1 - 1), z])
            else:
                centre = np.array([rng.uniform(x0 + 1, x1 - 1), wy + 0.01 * normal[1], z])
            kind = ("checker", "blocks")[i % 2]
            posters.append((kind, centre, upright_rotation(normal), side, _poster_texture(kind, rng)))
        return posters

    # ---- truth -------------------------------------------------------------------------------
    def hidden(self) -> dict:
        """The hall's geometry and lighting, for hidden.yaml."""
        def r(x):
            return [round(float(v), 6) for v in np.ravel(x)]

        return {
            "bounds_min_max_m": [r(self.bounds[0]), r(self.bounds[1])],
            "pillars_x_y_radius_m": [r(p) for p in self.pillars],
            "posters": [{"kind": k, "centre_m": r(c), "normal": r(R[:, 2]), "side_m": round(s, 6),
                         "cells": int(tex.shape[0])} for k, c, R, s, tex in self.posters],
            "ceiling_lights_x0_y0_x1_y1_m": [r(x) for x in self.lights],
            "surface_brightness": {k: v.hidden() for k, v in self.surface_light.items()},
            "marker_brightness": {k: v.hidden() for k, v in self.marker_light.items()},
            "marker_print_grey_levels": {"black": _INK, "white": _PAPER},
        }

    # ---- rendering ---------------------------------------------------------------------------
    def shade_room(self, origins, dirs, t: float) -> np.ndarray:
        """Grey levels (...) of the room's floor, walls and ceiling hit by rays ``origins`` + s · ``dirs``
        (..., 3) from inside the room, at true time t."""
        tr = t - self.start_time
        with np.errstate(divide="ignore", invalid="ignore"):
            far = np.where(dirs > 0, self.bounds[1], self.bounds[0])
            s_axis = (far - origins) / dirs
        s_axis = np.where(np.isfinite(s_axis) & (s_axis > 0), s_axis, np.inf)
        axis = np.argmin(s_axis, axis=-1)
        s = np.take_along_axis(s_axis, axis[..., None], axis=-1)[..., 0]
        hit = origins + s[..., None] * dirs
        x, y, z = hit[..., 0], hit[..., 1], hit[..., 2]
        grey = np.empty(s.shape, dtype=np.float32)
        # floor: tiles of varying grey with dark joints
        floor = (axis == 2) & (dirs[..., 2] < 0)
        ix, iy = np.floor(x[floor] / _TILE), np.floor(y[floor] / _TILE)
        tile = 105.0 + 30.0 * (np.sin(12.9898 * ix + 78.233 * iy) * 43758.5453 % 1.0)
        joint = (np.abs(x[floor] / _TILE - ix - 0.5) > 0.46) | (np.abs(y[floor] / _TILE - iy - 0.5) > 0.46)
        grey[floor] = np.where(joint, 60.0, tile) * self.surface_light["floor"](tr)
        # ceiling: light grey with saturating light panels
        ceiling = (axis == 2) & (dirs[..., 2] > 0)
        gx = (x[ceiling] - self._light_origin[0]) / _LIGHT_STEP
        gy = (y[ceiling] - self._light_origin[1]) / _LIGHT_STEP
        lit = ((np.abs(gx - np.round(gx)) * _LIGHT_STEP <= _LIGHT_HALF[0])
               & (np.abs(gy - np.round(gy)) * _LIGHT_STEP <= _LIGHT_HALF[1]) & (gx > -0.5) & (gy > -0.5))
        grey[ceiling] = np.where(lit, 900.0, 175.0 * self.surface_light["ceiling"](tr))
        # walls: panels with dark seams, darker below a dado line at 1 m
        for k, name in ((0, "wall_x"), (1, "wall_y")):
            wall = axis == k
            along = (y if k == 0 else x)[wall]
            seam = np.abs(along / _PANEL - np.floor(along / _PANEL) - 0.5) > 0.48
            level = np.where(z[wall] < 1.0, 110.0, 150.0) * (1.0 - 0.25 * seam)
            grey[wall] = level * self.surface_light[name](tr)
        return grey


def _poster_texture(kind: str, rng) -> np.ndarray:
    """A poster's grey levels (n, n) float32: a checker board of 6-10 cells, or 24×24 cells of white
    paper with dark blocks (text lines and pictures). Neither has an ArUco code's black frame with
    bits inside."""
    if kind == "checker":
        n = int(rng.integers(6, 11))
        i, j = np.indices((n, n))
        return np.where((i + j) % 2 == 0, 30.0, 220.0).astype(np.float32)
    n = 24
    tex = np.full((n, n), 225.0, dtype=np.float32)
    for _ in range(int(rng.integers(4, 9))):
        h, w = int(rng.integers(1, 6)), int(rng.integers(3, 12))
        r0, c0 = int(rng.integers(1, n - h)), int(rng.integers(1, n - w))
        tex[r0:r0 + h, c0:c0 + w] = rng.uniform(20.0, 120.0)
    return tex


@functools.lru_cache(maxsize=4)
def _low_res_bearings(width: int, factor: int) -> np.ndarray:
    """Camera-frame unit bearings (H/f, W/f, 3) at the centres of f×f pixel blocks; read-only, cached."""
    eq = Equirect(width, width // 2)
    u = factor * np.arange(width // factor) + (factor - 1) / 2.0
    v = factor * np.arange(width // 2 // factor) + (factor - 1) / 2.0
    b = eq.pixel_to_bearing(*np.meshgrid(u, v))
    b.flags.writeable = False
    return b


def _row_poses(scenario, t: float, height: int) -> np.ndarray:
    """map_T_camera (height, 4, 4) of each image row (the same pose in every row without a rolling shutter)."""
    if scenario.config.rolling_shutter_readout > 0.0:
        return scenario.map_T_camera(scenario.row_times(t, height))
    return np.broadcast_to(scenario.map_T_camera(float(t)), (height, 4, 4))


def _placed_per_row(camera_T_map_rows: np.ndarray, centre, map_R_face, item_id: int, size: float,
                    rolling: bool) -> PlacedMarker:
    """A face at ``centre`` (3,) in map, oriented ``map_R_face``, in the camera frame of each row
    (one placement when the rows share a pose)."""
    if not rolling:
        T = camera_T_map_rows[0]
        return PlacedMarker(item_id, size, T[:3, :3] @ centre + T[:3, 3], T[:3, :3] @ map_R_face)
    R = camera_T_map_rows[:, :3, :3]
    return PlacedMarker(item_id, size, R @ centre + camera_T_map_rows[:, :3, 3], R @ map_R_face)


def _centre_row(eq: Equirect, camera_T_rows: np.ndarray, point) -> int:
    """The image row (of the middle row's pose) through a map point; 0 with a single pose."""
    if camera_T_rows.shape[0] == 1:
        return 0
    T = camera_T_rows[camera_T_rows.shape[0] // 2]
    _, v = eq.bearing_to_pixel(T[:3, :3] @ point + T[:3, 3])
    return int(np.clip(round(float(v)), 0, camera_T_rows.shape[0] - 1))


def _splat_pillars(canvas, depth, eq: Equirect, hall: Hall, map_T_rows: np.ndarray, gain: float,
                   lenses: DualFisheye) -> None:
    """Paint the hall's pillars (vertical cylinders, floor to ceiling) where they are nearer than ``depth``,
    with edges anti-aliased over one pixel, each pixel seen along the ray of the lens with the larger share."""
    H, W = canvas.shape
    camera_T_map = invert_T(map_T_rows[[0, H // 2, H - 1]])
    ang = np.linspace(0.0, 2.0 * math.pi, 24, endpoint=False)
    heights = np.linspace(hall.bounds[0, 2], hall.bounds[1, 2], 7)
    light = np.array([0.6, 0.8])
    for px, py, radius in hall.pillars:
        ring = np.stack(np.broadcast_arrays(px + radius * np.cos(ang)[:, None], py + radius * np.sin(ang)[:, None],
                                            heights[None, :]), axis=-1).reshape(-1, 3)
        az, el = bearing_to_azel(np.einsum("kij,nj->kni", camera_T_map[:, :3, :3], ring)
                                 + camera_T_map[:, None, :3, 3])
        az_c = float(np.median(az))
        az_u = az_c + (az - az_c + math.pi) % (2.0 * math.pi) - math.pi
        u_a, _ = eq.azel_to_pixel(float(az_u.max()), 0.0)
        u_a = float(eq.unwrap_u(u_a, eq.azel_to_pixel(az_c, 0.0)[0]))
        pad = 3 + _lens_pad(eq, lenses)
        u0 = int(math.floor(u_a - pad))
        u1 = int(math.ceil(u_a + float(az_u.max() - az_u.min()) / eq.rad_per_px + pad))
        v0 = max(0, int(math.floor(float(eq.azel_to_pixel(0.0, float(el.max()))[1]) - pad)))
        v1 = min(H - 1, int(math.ceil(float(eq.azel_to_pixel(0.0, float(el.min()))[1]) + pad)))
        if u1 - u0 + 1 >= W:
            u0, u1 = 0, W - 1
        # shaded on every _PILLAR_ROW_STEP-th row and interpolated between (a pillar's edges are near vertical)
        rows = np.unique(np.r_[np.arange(v0, v1 + 1, _PILLAR_ROW_STEP), v1])
        uu, vv = np.meshgrid(np.arange(u0, u1 + 1, dtype=float), rows.astype(float))
        T = map_T_rows[rows]
        origin, d = _ray_origins_and_directions(eq.pixel_to_bearing(uu, vv), T, lenses)
        ox = origin[..., 0] - px
        oy = origin[..., 1] - py
        a = d[..., 0] ** 2 + d[..., 1] ** 2
        b = ox * d[..., 0] + oy * d[..., 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            miss = np.abs(ox * d[..., 1] - oy * d[..., 0]) / np.sqrt(a)  # ray's closest approach to the axis
            s = (-b - np.sqrt(np.maximum(b * b - a * (ox ** 2 + oy ** 2 - radius ** 2), 0.0))) / a
            s = np.where(np.isfinite(s), s, 1e6)
            z = T[:, None, 2, 3] + s * d[..., 2]
            reach = np.hypot(ox, oy)
            cover = np.clip(0.5 + (radius - miss) / (reach * eq.rad_per_px), 0.0, 1.0)
        cover = np.where((b < 0) & (z >= hall.bounds[0, 2]) & (z <= hall.bounds[1, 2]), cover, 0.0)
        hx, hy = ox + s * d[..., 0], oy + s * d[..., 1]  # hit point relative to the axis
        lambert = np.clip((hx * light[0] + hy * light[1]) / radius, 0.0, 1.0)
        grey = gain * (95.0 + 70.0 * lambert)
        size = (u1 - u0 + 1, v1 - v0 + 1)
        if rows.size > 1:
            y_map = np.interp(np.arange(v0, v1 + 1), rows, np.arange(rows.size)).astype(np.float32)[:, None]
            x_map = np.broadcast_to(np.arange(size[0], dtype=np.float32)[None, :], (size[1], size[0]))
            y_map = np.ascontiguousarray(np.broadcast_to(y_map, (size[1], size[0])))
            cover, s, grey = (cv2.remap(x.astype(np.float32), np.ascontiguousarray(x_map), y_map, cv2.INTER_LINEAR)
                              for x in (cover, s, grey))
        cover, s, grey = cover.astype(np.float32), s.astype(np.float32), grey.astype(np.float32)
        cols = np.arange(u0, u1 + 1) % W
        behind = depth[v0:v1 + 1][:, cols]
        cover = np.where(behind < s, np.float32(0.0), cover)
        if not cover.any():
            continue
        patch = canvas[v0:v1 + 1][:, cols]
        canvas[v0:v1 + 1, cols] = patch * (1.0 - cover) + grey * cover
        depth[v0:v1 + 1, cols] = np.where(cover >= 0.5, s, behind)


def _lens_pad(eq: Equirect, lenses: DualFisheye) -> float:
    """Pixels a lens's ray may be off the single-centre one for surfaces ≥ 0.5 m away (box padding)."""
    if lenses.single_centre:
        return 0.0
    return (lenses.lens_offset / 0.5 + float(np.linalg.norm(lenses.lens_rotation))) / eq.rad_per_px


def _ray_origins_and_directions(bearings: np.ndarray, map_T_rows: np.ndarray, lenses: DualFisheye):
    """Map-frame origins and unit directions (R, C, 3) of the rays of stitched camera bearings (R, C, 3), row r
    of the grid taken with the camera pose ``map_T_rows[r]``: from the centre of the lens with the larger share."""
    R = np.swapaxes(map_T_rows[:, :3, :3], -1, -2)
    t = map_T_rows[:, None, :3, 3]
    if lenses.single_centre:
        return np.broadcast_to(t, bearings.shape), np.matmul(bearings, R)
    origin, direction = lenses.rays(bearings)
    return t + np.matmul(origin, R), np.matmul(direction, R)


def _yaw_rate(scenario, t: float) -> float:
    """The camera's rotation rate about its own z axis (rad/s) at true time t."""
    h = 0.005
    R0, R1 = scenario.map_T_camera(np.array([t - h, t + h]))[:, :3, :3]
    dR = R0.T @ R1
    return math.atan2(dR[1, 0] - dR[0, 1], dR[0, 0] + dR[1, 1]) / (2.0 * h)


def _motion_blur(canvas: np.ndarray, length_px: float) -> None:
    """A horizontal box blur of ``length_px`` pixels (fractional ends), in place."""
    if length_px < 0.05:
        return
    half = int(math.ceil(length_px / 2.0 - 0.5))
    k = np.ones(2 * half + 1, dtype=np.float32)
    k[[0, -1]] = (length_px - (2 * half - 1)) / 2.0 if half > 0 else 1.0
    k /= k.sum()
    cv2.filter2D(canvas, -1, k[None, :], dst=canvas, borderType=cv2.BORDER_REPLICATE)


def render_frame(scenario, index: int, profile: Optional[render.RenderProfile] = None) -> np.ndarray:
    """Frame ``index`` of ``scenario`` as a grey image (H, W) uint8, before the bag's JPEG step
    (``profile``: the scenario's render profile without its JPEG unless given)."""
    import dataclasses

    c = scenario.config
    p = profile or dataclasses.replace(render.PROFILES[c.profile], jpeg_quality=None)
    t = float(scenario.frame_times[index])
    noise_seed = (c.seed << 20) + index
    effects = (c.rolling_shutter_readout, c.exposure_time, c.exposure_wander, not scenario.lenses.single_centre)
    if scenario.world is None and not any(effects):
        return render.render_equirect(c.width, scenario.placed_markers(t), dictionary=c.dictionary, profile=p,
                                      seed=c.seed, background_yaw=float(scenario.camera_yaw(t)),
                                      noise_seed=noise_seed)
    W, H = c.width, c.width // 2
    eq = Equirect(W, H)
    map_T_rows = _row_poses(scenario, t, H)
    camera_T_rows = invert_T(map_T_rows if c.rolling_shutter_readout > 0 else map_T_rows[:1])
    rolling = c.rolling_shutter_readout > 0
    hall: Optional[Hall] = scenario.world
    tr = t - c.start_time
    if hall is None and p.background == "grey":
        canvas = np.full((H, W), float(render._GREY_LEVEL), dtype=np.float32)
    elif hall is None:  # the easy world's panorama behind the markers
        shift = int(round(float(scenario.camera_yaw(t)) / eq.rad_per_px))
        canvas = np.roll(render._background(W, int(c.seed)), shift, axis=1).astype(np.float32)
    else:
        f = _LOW_RES
        rows = f * np.arange(H // f) + (f - 1) // 2
        origins, dirs = _ray_origins_and_directions(_low_res_bearings(W, f), map_T_rows[rows], scenario.lenses)
        low = hall.shade_room(origins, dirs, tr)
        # softened before scaling up: the block steps of a one-sample-per-block edge become a smooth line
        cv2.GaussianBlur(low, (0, 0), 0.6, dst=low, borderType=cv2.BORDER_REPLICATE)
        canvas = cv2.resize(low, (W, H), interpolation=cv2.INTER_LINEAR)
    depth = np.full((H, W), np.inf, dtype=np.float32)
    if hall is not None:
        g = hall.surface_light["posters"](tr)
        for k, (_, centre, R, side, tex) in enumerate(hall.posters):
            # a poster takes the pose of the row through its centre (with a rolling shutter: shifted, not
            # sheared; they are distractors, the markers get every row's pose)
            face = _placed_per_row(camera_T_rows[_centre_row(eq, camera_T_rows, centre):][:1], centre, R, k, side,
                                   False)
            render._splat_marker(canvas, eq, face, tex, tex.shape[0], 2, depth=depth, light=(g, 0.0),
                                 lenses=scenario.lenses)
    n_black = render._marker_bit_count(c.dictionary)
    for m in scenario.markers:
        face = _placed_per_row(camera_T_rows, np.asarray(m.position, dtype=float), scenario.map_R_marker(m.id),
                               m.id, m.size, rolling)
        if hall is None:
            gain, offset = 1.0, 0.0
        else:  # printed black and white under this marker's light
            light = hall.marker_light[int(m.id)](tr)
            gain, offset = light * (_PAPER - _INK) / 255.0, light * _INK
        render._splat_marker(canvas, eq, face, render._marker_bits(c.dictionary, m.id), n_black, p.supersample,
                             depth=depth, light=(gain, offset), lenses=scenario.lenses)
    impostor = scenario.impostor(t)
    if impostor is not None:
        render._splat_marker(canvas, eq, impostor, render._marker_bits(c.dictionary, impostor.id), n_black,
                             p.supersample, depth=depth, lenses=scenario.lenses)
    if hall is not None:
        _splat_pillars(canvas, depth, eq, hall, map_T_rows, hall.surface_light["pillars"](tr), scenario.lenses)
    if c.exposure_wander > 0:
        canvas *= np.float32(scenario.exposure_gain(t))
    _motion_blur(canvas, abs(_yaw_rate(scenario, t)) * c.exposure_time / eq.rad_per_px)
    np.minimum(canvas, 255.0, out=canvas)  # saturation before the noise (a clipped highlight stays white)
    return finish_frame(canvas, p, int(c.seed), noise_seed)
