"""The detector: an equirect frame in, one :class:`~.observation.MarkerObservation` per marker out.

In: a grey or colour equirect frame (2:1, uint8) and :class:`~.params.DetectorParams`.
Out: the frame's markers sorted by id (:meth:`MarkerDetector.detect`: whole frame, the strip
around the ±180° seam, the two polar views), or the markers of a column strip or of gnomonic
views (:meth:`MarkerDetector.detect_columns`, :meth:`~MarkerDetector.detect_in_view`,
:meth:`~MarkerDetector.detect_in_views`, which :mod:`aruco_abs_orient.tracking` uses). Chains
the stages: :mod:`.backend` (OpenCV) → :mod:`.sphere` / :mod:`.quads` (edge refinement,
re-reading OpenCV's ids, reading the quads it rejected) → :mod:`.observation` (records, one per
marker).
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Collection, Dict, List, Mapping, NamedTuple, Optional, Sequence, Tuple

import cv2
import numpy as np

from ..camera import Equirect, GnomonicView
from .backend import ArucoBackend
from .images import to_grey
from .jpegrows import bilinear_rows, need_rows, partial
from .observation import MarkerObservation, bearing_sigma, dedupe_observations
from .params import DetectorParams
from .quads import decode_quads, image_sampler, quiet_zone_contrast, refine_quads
from .sphere import decode_markers, fit_patterns_many, marker_angular_size, refine_corners_many, sphere_centre_bearing

__all__ = ["MarkerDetector", "Wanted"]


class Wanted(NamedTuple):
    """Which markers a search keeps: ``expect_id`` only this id (tracking: OpenCV's reading of the predicted
    id at the predicted place is not re-verified; None: any id); ``rescue``: also decode the quads OpenCV
    rejected (small, close markers); ``skip_ids``: ids OpenCV read that are not wanted (already observed)."""

    expect_id: Optional[int] = None
    rescue: bool = True
    skip_ids: Collection[int] = ()


_ANY = Wanted()


class _Searched(NamedTuple):
    """An image OpenCV searched: ``image`` its pixels; ``to_bearing(x, y)`` its pixels to bearings; ``scale``
    its pixels per equirect pixel; ``perspective``: it is a gnomonic view with exact enough maps (corners
    are refined and read in it directly), else an equirect strip (refined on the sphere,
    :func:`refine_corners`)."""

    image: np.ndarray
    to_bearing: Callable
    scale: float
    perspective: bool


def _tiles(quads: np.ndarray, tops: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """The mosaic tile (view index) wholly holding each quad (M, 4, 2), -1 where none: tile k spans
    rows ``tops[k]`` to ``tops[k] + sizes[k, 0]`` and columns 0 to ``sizes[k, 1]``; a quad belongs to
    the tile its centre's row falls in."""
    k = np.searchsorted(tops, quads[:, :, 1].mean(axis=1), side="right") - 1
    kk = np.clip(k, 0, len(sizes) - 1)
    inside = ((k >= 0) & (k < len(sizes)) & (quads[:, :, 1].max(axis=1) < tops[kk] + sizes[kk, 0])
              & (quads[:, :, 0].max(axis=1) < sizes[kk, 1]))
    return np.where(inside, k, -1)


class MarkerDetector:
    """Full-frame ArUco detection in equirect frames, seam- and pole-aware.

    >>> det = MarkerDetector("DICT_4X4_50")          # doctest: +SKIP
    >>> observations = det.detect(grey_equirect)     # doctest: +SKIP
    """

    def __init__(self, dictionary: str = "DICT_4X4_50", params: Optional[DetectorParams] = None,
                 api: Optional[str] = None):
        self.params = params if params is not None else DetectorParams()
        self.params.validate()
        self.backend = ArucoBackend(dictionary, self.params, api)
        self._pole_maps: Dict[Tuple[int, int], Tuple[GnomonicView, np.ndarray, np.ndarray]] = {}
        self._threads: Optional[Tuple[int, ThreadPoolExecutor]] = None

    # ---------------------------------------------------------------- building blocks

    def observation(self, equirect: Equirect, marker_id: int, corners: np.ndarray,
                    method: str) -> MarkerObservation:
        """A record from corner bearings (4, 3) in ArUco order."""
        return self.observations(equirect, [marker_id], np.asarray(corners)[None], method)[0]

    def observations(self, equirect: Equirect, ids: Sequence[int], corners: np.ndarray,
                     method: str, grey: Optional[np.ndarray] = None) -> List[MarkerObservation]:
        """Records from corner bearings (M, 4, 3) in ArUco order, all at once; given the ``grey`` equirect they
        were found in, the corners of the small ones fitted with their whole pattern first (``pattern_fit``)."""
        corners = np.asarray(corners, dtype=float).reshape(-1, 4, 3)
        fitted = np.zeros(len(corners), dtype=bool)
        if grey is not None:
            corners, fitted = self._pattern_fitted(grey, equirect, ids, corners)
        centres = sphere_centre_bearing(corners)
        u, v = equirect.bearing_to_pixel(np.concatenate([centres[:, None], corners], axis=1))  # (M, 5)
        cu = equirect.unwrap_u(u[:, 1:], u[:, 1:2])
        sizes = np.atleast_1d(marker_angular_size(corners))
        out = []
        for k, marker_id in enumerate(ids):
            side_px = float(sizes[k]) / equirect.rad_per_px
            out.append(MarkerObservation(
                id=int(marker_id), corners=corners[k], centre=centres[k], pixel=(float(u[k, 0]), float(v[k, 0])),
                corners_px=np.stack([cu[k], v[k, 1:]], axis=1), angular_size=float(sizes[k]),
                sigma=bearing_sigma(self.params, equirect.rad_per_px, side_px, method, bool(fitted[k])), method=method,
                side_px=side_px))
        return out

    def _pattern_fitted(self, grey: np.ndarray, equirect: Equirect, ids: Sequence[int],
                        corners: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """``corners`` (M, 4, 3) with those of the markers whose cells are at most ``pattern_fit_max_cell_px``
        wide fitted with their pattern (:func:`.sphere.fit_patterns_many`) where the fit succeeds, and which
        were (M,) bool."""
        q = self.params
        done = np.zeros(len(corners), dtype=bool)
        if not q.pattern_fit or not len(corners):
            return corners, done
        cell_px = np.atleast_1d(marker_angular_size(corners)) / (equirect.rad_per_px * self.backend.bits)
        small = np.flatnonzero(cell_px <= q.pattern_fit_max_cell_px)
        if not len(small):
            return corners, done
        codes = self.backend.codes[np.asarray(ids, dtype=int)[small]]
        fitted = fit_patterns_many(grey, equirect, corners[small], codes, q.pattern_fit_params())
        ok = ~np.isnan(fitted).any(axis=(1, 2))
        out = corners.copy()
        out[small[ok]] = fitted[ok]
        done[small[ok]] = True
        return out, done

    def _finish(self, grey: np.ndarray, equirect: Equirect, found: Tuple[List[int], List[np.ndarray],
                List[np.ndarray]], searched: _Searched, method: str, wanted: Wanted = _ANY) -> List[MarkerObservation]:
        """Observations from a backend result ``found`` in the ``searched`` image: edge-refined corners of the
        decoded markers, plus rejected quads decoded here (small ones up to ``rescue_max_side_px``, large
        ones from ``close_range_size_deg``), as many as are ``wanted``.
        """
        image, to_bearing, scale, perspective = searched
        expect_id, rescue, skip_ids = wanted
        q = self.params
        bits = self.backend.bits
        codes = self.backend.codes
        ids, corners, rejected = found
        sample = image_sampler(image)
        out = []
        wanted = [k for k, i in enumerate(ids) if not ((expect_id is not None and i != expect_id) or i in skip_ids)]
        if wanted:  # OpenCV's finds, refined (and read again) all at once
            kept_ids = [ids[k] for k in wanted]
            c = np.array([corners[k] for k in wanted])
            b = to_bearing(c[..., 0], c[..., 1])
            if q.edge_refine and perspective:
                rq = refine_quads(sample, c, bits, q.view_refine_iterations, q.edge_fit())
                b = np.where(np.isnan(rq).any(axis=(1, 2))[:, None, None], b, to_bearing(rq[..., 0], rq[..., 1]))
            elif q.edge_refine:
                rb = refine_corners_many(grey, equirect, b, bits, fit=q.edge_fit())
                b = np.where(np.isnan(rb).any(axis=(1, 2))[:, None, None], b, rb)
            if q.verify_decode and expect_id is None:
                # OpenCV's id must be what the cells say (else a misread or a texture)
                hits = decode_markers(grey, equirect, b, codes, self.params.decode())
                same = [k for k, (i, hit) in enumerate(zip(kept_ids, hits)) if hit is not None and hit[0] == i]
                kept_ids, b = [kept_ids[k] for k in same], b[same]
            if kept_ids:
                out += self.observations(equirect, kept_ids, b, method, grey)
        if not rescue or (expect_id is not None and out):
            return out
        small = q.rescue_max_side_px * 4.0 * scale
        large = math.radians(q.close_range_size_deg) / equirect.rad_per_px * 4.0 * scale
        # a small quad is the black square, the outline of its white quiet zone or a looser one
        # (rescue_shrink): all refined and read at once in the image, then (equirect) again on
        # the sphere; a large one may be a close marker whose curved equirect image OpenCV
        # could not read: in a view read at once, in the equirect on the sphere only.
        rejected = np.array(rejected, dtype=float).reshape(-1, 4, 2)
        perimeters = np.sum(np.linalg.norm(rejected - np.roll(rejected, -1, axis=1), axis=2), axis=1)
        mid = rejected.mean(axis=1, keepdims=True)
        shrunk = mid[:, None] + np.asarray(q.rescue_shrink)[None, :, None, None] * (rejected - mid)[:, None]
        tries = shrunk[(perimeters <= small) | (perspective & (perimeters >= large))]   # (M, S, 4, 2)
        if len(tries) and q.rescue_min_contrast > 0:  # most are texture: no dark square in a bright quiet zone
            contrast = quiet_zone_contrast(sample, tries.reshape(-1, 4, 2), bits).reshape(tries.shape[:2])
            tries = tries[contrast.max(axis=1) >= q.rescue_min_contrast]
        tries = tries.reshape(-1, 4, 2)
        refined = refine_quads(sample, tries, bits, fit=q.edge_fit())
        refined = refined[~np.isnan(refined).any(axis=(1, 2))]
        hits = [h for h in decode_quads(sample, refined, codes, self.params.decode())
                if h is not None and (expect_id is None or h[0] == expect_id)]
        if hits and perspective:
            out += self.observations(equirect, [h[0] for h in hits],
                                     np.array([to_bearing(h[1][:, 0], h[1][:, 1]) for h in hits]), method, grey)
        elif hits:  # read in the equirect: straighten on the sphere, read again
            # the shrunk tries of one marker read as the same square: one (the next only if it fails)
            b = np.array([to_bearing(h[1][:, 0], h[1][:, 1]) for h in hits])
            out += self._refined_and_read(grey, equirect, b, [h[0] for h in hits], method, keys=_same_squares(hits))
        if not perspective:  # large quads in the equirect: curved edges, refined on the sphere only
            big = perimeters >= large
            if np.any(big):
                quads = shrunk[big].reshape(-1, 4, 2)
                b = to_bearing(quads[..., 0], quads[..., 1])
                # a quick loose reading first: most large quads are texture
                loose = [k for k, h in enumerate(decode_markers(grey, equirect, b, codes, q.loose_decode()))
                         if h is not None]
                got = self._refined_and_read(grey, equirect, b[loose], [expect_id] * len(loose), method,
                                             keys=[k // len(q.rescue_shrink) for k in loose])
                out += got
        return dedupe_observations(out)

    def _refined_and_read(self, grey: np.ndarray, equirect: Equirect, corners: np.ndarray,
                          expect: Sequence[Optional[int]], method: str,
                          keys: Optional[Sequence[int]] = None) -> List[MarkerObservation]:
        """Observations of candidate quads (corner bearings (M, 4, 3)) of the equirect whose
        corners refine on the sphere and whose cells then read as the ``expect`` id (None:
        any id). With ``keys`` (the shrunk tries of one rejected quad share a key), a key's
        tries are taken in order, the next one only when the previous failed."""
        keys = list(range(len(corners))) if keys is None else list(keys)
        ids, bearings = [], []
        todo = list(range(len(corners)))
        while todo:
            batch, seen = [], set()
            for k in todo:  # the first untried try of each key
                if keys[k] not in seen:
                    seen.add(keys[k])
                    batch.append(k)
            rb = refine_corners_many(grey, equirect, corners[batch], self.backend.bits, fit=self.params.edge_fit())
            good = np.flatnonzero(~np.isnan(rb).any(axis=(1, 2)))
            hits = decode_markers(grey, equirect, rb[good], self.backend.codes, self.params.decode())
            done = set()
            for j, hit in zip(good, hits):
                k = batch[j]
                if hit is not None and (expect[k] is None or hit[0] == expect[k]):
                    done.add(keys[k])
                    ids.append(hit[0])
                    bearings.append(hit[1])
            todo = [k for k in todo if k not in batch and keys[k] not in done]
        return self.observations(equirect, ids, np.array(bearings), method, grey) if ids else []

    def detect_in_view(self, grey: np.ndarray, equirect: Equirect, view: GnomonicView, method: str,
                       maps: Optional[Tuple[np.ndarray, np.ndarray]] = None, map_step: int = 1,
                       expect_id: Optional[int] = None) -> List[MarkerObservation]:
        """Markers in a gnomonic view of the equirect frame (corners refined in a view).

        ``maps``: precomputed :meth:`view_maps`, for reused views; else computed exactly
        (``map_step`` 1) or interpolated between every ``map_step`` view pixels (≤ 4: exact
        enough to refine corners in the view image itself).
        ``expect_id``: only this id is wanted (see :class:`Wanted`).
        """
        if maps is None:
            maps = view.remap_maps(equirect, map_step)
        img = cv2.remap(grey, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        scale = view.focal * equirect.rad_per_px  # view pixels per equirect pixel at its centre
        found = self.backend.detect(img, self.params.min_marker_perimeter_px * scale)
        return self._finish(grey, equirect, found, _Searched(img, view.pixel_to_bearing, scale, map_step <= 4),
                            method, Wanted(expect_id))

    def detect_in_views(self, grey: np.ndarray, equirect: Equirect, views: Sequence[GnomonicView],
                        maps: Sequence[Tuple[np.ndarray, np.ndarray]], expect_ids: Sequence[int],
                        method: str = "tracked", expect_sizes: Optional[Sequence[float]] = None, *,
                        gate: float) -> List[MarkerObservation]:
        """The expected marker in each of several small gnomonic views, in one OpenCV call.

        The views (with their :meth:`view_maps`, step ≤ 4) are rendered into one mosaic
        (stacked, separated by flat grey rows), OpenCV searches it once, every find is
        assigned to its view and kept only if it is that view's ``expect_ids`` entry; its
        corners are edge-refined in the view image. Views whose marker OpenCV did not read
        get their rejected quads within ``gate`` (radians: the tracking gate) of the view centre decoded
        (:func:`decode_quads`), as in :meth:`detect`; with ``expect_sizes`` (predicted
        angular sizes, radians) only quads within ``view_size_tolerance`` (35 %) of that size are tried.
        """
        if not views:
            return []
        gap = 8
        for _, my in maps if partial(grey) else ():  # float maps: the rows each view reads
            need_rows(grey, *bilinear_rows(my))
        imgs = [cv2.remap(grey, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP) for mx, my in maps]
        tops = np.cumsum([0] + [im.shape[0] + gap for im in imgs])
        mosaic = np.full((int(tops[-1]) - gap, max(im.shape[1] for im in imgs)), 128, np.uint8)
        for im, y0 in zip(imgs, tops):
            mosaic[y0:y0 + im.shape[0], :im.shape[1]] = im
        scale = min(v.focal for v in views) * equirect.rad_per_px
        ids, corners, rejected = self.backend.detect(mosaic, self.params.min_marker_perimeter_px * scale)
        sample = image_sampler(mosaic)
        bits, q = self.backend.bits, self.params
        found = set()

        def add(k, marker_id, quad):
            view, y0 = views[k], float(tops[k])
            bearings.append(view.pixel_to_bearing(quad[:, 0], quad[:, 1] - y0))
            marker_ids.append(marker_id)
            found.add(k)

        bearings, marker_ids = [], []

        sizes = np.array([im.shape for im in imgs])
        keep = {}
        for i, c, k in zip(ids, corners, _tiles(np.array(corners, dtype=float).reshape(-1, 4, 2), tops, sizes)):
            if k >= 0 and i == expect_ids[k] and k not in keep:
                keep[int(k)] = c

        rejected = np.array(rejected, dtype=float).reshape(-1, 4, 2)
        tries = self._view_tries(rejected, _tiles(rejected, tops, sizes), views, tops, keep, expect_sizes, gate)
        # OpenCV's finds and the rejected quads worth reading, refined in one batch; OpenCV's
        # corners in a view are close: short profiles do (12 × 12 per edge)
        batch = [(k, keep[k], True) for k in keep] + [(k, quad, False) for k, quad in tries]
        if not batch:
            return []
        quads = np.array([b[1] for b in batch])
        refined = (refine_quads(sample, quads, bits, q.view_refine_iterations, q.edge_fit(view=True))
                   if q.edge_refine or tries else quads)
        readable = [j for j, ((_, _, by_opencv), r) in enumerate(zip(batch, refined))
                    if not by_opencv and not np.isnan(r).any()]
        hits = dict(zip(readable, decode_quads(sample, refined[readable], self.backend.codes, q.decode())))
        for j, ((k, c, read_by_opencv), r) in enumerate(zip(batch, refined)):
            if read_by_opencv:
                add(k, expect_ids[k], c if (np.isnan(r).any() or not q.edge_refine) else r)
            elif k not in found and hits.get(j) is not None and hits[j][0] == expect_ids[k]:
                add(k, hits[j][0], hits[j][1])
        return self.observations(equirect, marker_ids, np.array(bearings), method, grey) if bearings else []

    def _view_tries(self, rejected: np.ndarray, tiles: np.ndarray, views: Sequence[GnomonicView],
                    tops: np.ndarray, keep: Mapping[int, np.ndarray], expect_sizes: Optional[Sequence[float]],
                    gate: float) -> List[Tuple[int, np.ndarray]]:
        """:meth:`detect_in_views`' rejected quads worth reading, ``(view k, quad (4, 2))`` in the order of
        ``rejected`` (M, 4, 2) and ``rescue_shrink``: those wholly inside a view (``tiles``: :func:`_tiles`)
        OpenCV found nothing in (not in ``keep``), centred within ``gate`` of its centre, shrunk by each
        ``rescue_shrink`` and (with ``expect_sizes``) of the expected size within ``view_size_tolerance``."""
        q = self.params
        centre = rejected.mean(axis=1)                                        # (M, 2)
        kk = np.maximum(tiles, 0)
        focal = np.array([v.focal for v in views])
        axis = np.array([(v.cx, v.cy) for v in views]) + np.stack([np.zeros(len(views)), tops[:-1]], axis=1)
        ok = ((tiles >= 0) & ~np.isin(kk, list(keep))
              & (np.hypot(*(centre - axis[kk]).T) <= math.tan(gate) * focal[kk] + 2.0))
        shrunk = centre[:, None, None] + np.asarray(q.rescue_shrink)[None, :, None, None] \
            * (rejected - centre[:, None])[:, None]                          # (M, S, 4, 2)
        plausible = np.ones(shrunk.shape[:2], dtype=bool)
        if expect_sizes is not None:
            side = np.linalg.norm(shrunk - np.roll(shrunk, -1, axis=2), axis=3).mean(axis=2)
            expected = np.asarray(expect_sizes, dtype=float)[kk] * focal[kk]
            plausible = np.abs(side / expected[:, None] - 1.0) <= q.view_size_tolerance
        return [(int(kk[m]), shrunk[m, j]) for m, j in np.argwhere(ok[:, None] & plausible)]

    def detect_columns(self, grey: np.ndarray, equirect: Equirect, u0: int, width: int,
                       method: str = "full", max_el: float = math.pi / 2, across: Optional[float] = None,
                       wanted: Wanted = _ANY) -> List[MarkerObservation]:
        """Markers in the vertical strip of columns [u0, u0 + width) (wrapping around the seam),
        rows within ``max_el`` (radians) of the horizon; ``across``: only OpenCV's finds and rejected
        quads that reach across this column of the strip (with half their width to spare, for the
        refinement) are refined and read; ``wanted``: :class:`Wanted` (``rescue``, ``skip_ids``)."""
        w = equirect.width
        u0 = int(u0) % w
        width = int(min(width, w))
        v0, v1 = band_rows(equirect, max_el)
        need_rows(grey, v0, v1)
        if u0 + width <= w:
            strip = grey[v0:v1, u0:u0 + width]
        else:
            strip = np.hstack([grey[v0:v1, u0:], grey[v0:v1, :u0 + width - w]])
        found = self.backend.detect(strip, self.params.min_marker_perimeter_px)
        if across is not None:
            ids, corners, rejected = found
            near = [_reaches(c, across) for c in corners]
            found = ([i for i, ok in zip(ids, near) if ok], [c for c, ok in zip(corners, near) if ok],
                     [c for c in rejected if _reaches(c, across)])
        searched = _Searched(strip, lambda x, y: equirect.pixel_to_bearing(x + u0, y + v0), 1.0, False)
        return self._finish(grey, equirect, found, searched, method, wanted)

    @staticmethod
    def view_maps(view: GnomonicView, equirect: Equirect, step: int = 1) -> Tuple[np.ndarray, np.ndarray]:
        """Remap maps equirect → ``view`` for :meth:`detect_in_view` (``GnomonicView.remap_maps``)."""
        return view.remap_maps(equirect, step)

    def view_around(self, equirect: Equirect, centre, fov: float, upsample: float = 1.0,
                    min_px: int = 1) -> GnomonicView:
        """A square gnomonic view of full field of view ``fov`` (radians) around a bearing, at
        ``upsample`` × the equirect resolution, at least ``min_px`` and at most ``max_view_px`` pixels."""
        fov = min(max(fov, 1e-3), math.radians(150.0))
        native = 2.0 * math.tan(fov / 2.0) / equirect.rad_per_px
        size = int(min(max(math.ceil(native * upsample), min_px), self.params.max_view_px))
        return GnomonicView.around(equirect, centre, fov, size=size)

    def _pool(self) -> Optional[ThreadPoolExecutor]:
        """Threads for :meth:`detect`'s seam and polar searches (one each) when OpenCV has
        threads (``cv2.setNumThreads``); None when it runs single-threaded."""
        n = min(2, cv2.getNumThreads())
        if n <= 1:
            return None
        if self._threads is None or self._threads[0] != n:
            if self._threads is not None:
                self._threads[1].shutdown(wait=False)
            self._threads = (n, ThreadPoolExecutor(max_workers=n, thread_name_prefix="aruco_detect"))
        return self._threads[1]

    def _pole_views(self, equirect: Equirect):
        key = (equirect.width, equirect.height)
        if key not in self._pole_maps:
            fov = 2.0 * math.radians(90.0 - self.params.pole_band_deg + 5.0)
            views = []
            for z in (1.0, -1.0):
                view = self.view_around(equirect, np.array([0.0, 0.0, z]), fov)
                map_x, map_y = view.remap_maps(equirect)
                # columns brought into [0, W) once (cv2.remap is ~2× slower on columns it must wrap), in the
                # fixed-point form cv2.remap converts float maps to on every call (the same pixels, 1/4 less time)
                views.append((view, cv2.convertMaps(np.mod(map_x, np.float32(equirect.width)), map_y,
                                                    cv2.CV_16SC2)))
            self._pole_maps = {key: views}
        return self._pole_maps[key]

    # ---------------------------------------------------------------- the full pipeline

    def detect(self, image: np.ndarray, what: str = "image") -> List[MarkerObservation]:
        """All markers of an equirect frame (grey or BGR uint8, 2:1): full frame, the strip
        around the ±180° seam, the two polar views; corners edge-refined in gnomonic views;
        one observation per physical marker, sorted by id. Raises DetectionError for an
        unusable image.
        """
        grey = to_grey(image, what)
        need_rows(grey, 0, grey.shape[0])
        eq = Equirect(grey.shape[1], grey.shape[0])
        q = self.params
        # with the polar views, the equirect is searched up to pole_overlap_deg beyond their band
        max_el = math.radians(min(q.pole_band_deg + q.pole_overlap_deg, 90.0)) if q.pole_views else math.pi / 2
        half = int(math.ceil(math.radians(q.seam_strip_deg) / eq.rad_per_px))
        band = math.radians(q.pole_band_deg)
        extra = []  # searches independent of the full pass, run beside it (OpenCV releases the GIL)
        if half > 0:
            extra.append(lambda: [o for o in self.detect_columns(grey, eq, eq.width - half, 2 * half, "seam",
                                                                 max_el=max_el, across=half - 0.5)
                                  if _straddles_seam(o, eq)])
        if q.pole_views:  # one job: the two views share one OpenCV detector (their rate is the same)
            extra.append(lambda: [[o for o in self.detect_in_view(grey, eq, view, "gnomonic", maps)
                                   if abs(o.elevation) > band] for view, maps in self._pole_views(eq)])
        pool = self._pool()
        pending = [pool.submit(job) for job in extra] if pool is not None else []
        found = self.detect_columns(grey, eq, 0, eq.width, "full", max_el=max_el)
        results = [p.result() for p in pending] if pool is not None else [job() for job in extra]
        if half > 0:
            found = dedupe_observations(found + results.pop(0))
        for polar in (results[0] if results else []):
            found = dedupe_observations(found + polar)
        return sorted(found, key=lambda o: o.id)


def band_rows(equirect: Equirect, max_el: float) -> Tuple[int, int]:
    """The rows [v0, v1) of the band within ``max_el`` (radians) of the horizon that a strip search reads."""
    v0 = int(max(0, math.floor(equirect.azel_to_pixel(0.0, max_el)[1])))
    v1 = int(min(equirect.height, math.ceil(equirect.azel_to_pixel(0.0, -max_el)[1]) + 1))
    return v0, v1


def _same_squares(hits: Sequence[Tuple[int, np.ndarray]]) -> List[int]:
    """A key per decoded quad ``(id, corners (4, 2))``: the same key for quads of the same id
    whose centres are within a quarter of a side of each other (one marker read twice)."""
    keys: List[int] = []
    for k, (marker_id, q) in enumerate(hits):
        centre = q.mean(axis=0)
        side = float(np.mean(np.linalg.norm(q - np.roll(q, -1, axis=0), axis=1)))
        same = [keys[j] for j in range(k) if hits[j][0] == marker_id
                and float(np.hypot(*(hits[j][1].mean(axis=0) - centre))) < 0.25 * side]
        keys.append(same[0] if same else k)
    return keys


def _reaches(quad: np.ndarray, column: float) -> bool:
    """True when a quad's columns (4, 2), widened by half their span each way, contain ``column``."""
    lo, hi = float(quad[:, 0].min()), float(quad[:, 0].max())
    return lo - 0.5 * (hi - lo) <= column <= hi + 0.5 * (hi - lo)


def _straddles_seam(obs: MarkerObservation, equirect: Equirect) -> bool:
    """True when the marker's corners lie on both sides of the ±180° seam (column −0.5 ≡ W−0.5)."""
    u = obs.corners_px[:, 0]
    return bool(u.min() < -0.5 < u.max() or u.min() < equirect.width - 0.5 < u.max())
