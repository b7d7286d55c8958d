"""The report's pictures: each answers one question in its title, and shows what the answer rests on.

In: results of :mod:`.evaluation` (``YawErrors``, ``MarkerAgreement``, ``PairwiseDifferences``,
``FramePositionBias``), time-offset estimates (``timesync.OffsetEstimate`` and the marker bearings' residual
against the offset), a ``calibration.Calibration`` with its observations' bearings, a 360° frame with the map's
markers where they should be. Out: PNG files, written atomically, whose title is the answer with its numbers
("time offset 367.7 ± 0.2 ms: the marker bearings agree best there"); the title is also stored in the PNG's
``Title`` text chunk (:func:`png_title` reads it back), so programs and tests read what a person reads.

Contract: 1000 px wide and 12 pt text, readable where report.md shows them; degrees, milliseconds and seconds
since the start of the recording on the axes; a bad run looks different from a good one in the title first.
How a figure is drawn and written (canvas, style, the PNG's title) is ``figures.py``'s: ``figure``,
``save_figure``, ``png_title`` and ``WIDTH`` are importable from here too.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Mapping, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from .camera import bearing_to_azel
from .figures import _BAD, _GOOD, WIDTH, _deg, _finish, _style, _title, figure, png_title, save_figure
from .transforms import rpy_to_matrix

__all__ = ["WIDTH", "HeadingCurve", "Span", "figure", "save_figure", "png_title", "plot_time_offset",
           "plot_marker_agreement", "plot_heading_error", "plot_frame_position", "mounting_turn", "calibration_answer",
           "plot_calibration", "plot_overview"]

# --------------------------------------------------------------------------- time offset


def _offset_answer(best, refined: bool, in_use: Optional[float]) -> Tuple[str, bool]:
    """(title, whether the offset in use is off) for the best estimate ``best`` (OffsetEstimate)."""
    tau, sigma = 1e3 * best.offset, 1e3 * best.sigma
    used = None if in_use is None else 1e3 * in_use
    off = used is not None and abs(used - tau) > max(3.0 * sigma, 0.5)
    if not refined:
        head = (f"time offset {tau:.1f} ± {sigma:.1f} ms" if used is None else
                f"time offset in use {used:.1f} ms ({used - tau:+.1f} ms from {tau:.1f} ± {sigma:.1f} ms)")
        basis = ("the marker bearings agree best on the scan's grid" if best.method == "marker scan" else
                 "the VO heading follows the prism track best")
        # a coarse σ cannot judge an offset refined elsewhere
        return (head + f": where {basis}; refine it with the marker bearings (timesync --markers)"), False
    if used is None:
        return f"time offset {tau:.1f} ± {sigma:.1f} ms: the marker bearings agree best there", False
    if off:
        return (f"time offset in use {used:.1f} ms is {used - tau:+.1f} ms off: the marker bearings agree best at "
                f"{tau:.1f} ± {sigma:.1f} ms"), True
    return f"time offset in use {used:.1f} ms: the marker bearings agree best there ({tau:.1f} ± {sigma:.1f} ms)", False


def plot_time_offset(path: str, coarse, refined=None, cost: Optional[Tuple[np.ndarray, np.ndarray]] = None,
                     in_use: Optional[float] = None, baseline=None, size: Tuple[int, int] = (WIDTH, 680)) -> str:
    """Is the time offset right? The answer in the title (the marker bearings' offset ± σ, or the coarse one's,
    and how far the offset ``in_use`` by a run (s) is from it); below, what it rests on: ``cost`` = (offsets s,
    RMS of the marker bearings' residuals rad with the offset held there) with the minimum and its σ band, and
    the coarse estimate ``coarse`` (an ``OffsetEstimate`` of the VO heading: its coherence curve; or the marker
    scan's, method "marker scan": its residual over the whole search) as context,
    with the paper's cross-correlation peak (``baseline``) marked. ``refined``: the marker-bearing
    ``OffsetEstimate`` (None: the coarse one is the answer). Offsets in ms, camera stamp − total-station time."""
    best = refined if refined is not None else coarse
    answer, off = _offset_answer(best, refined is not None, in_use)

    def ms(seconds):
        return 1e3 * np.asarray(seconds, dtype=float)

    scan = coarse.method == "marker scan"   # the heading gave none: the marker bearings over the whole search
    spans = [ms(coarse.offset) + ms(coarse.sigma) * np.array([-2.0, 2.0]), ms(best.offset) + np.array([-30.0, 30.0])]
    if scan and len(coarse.taus):
        spans.append(ms(coarse.taus))
    have_cost = cost is not None and len(cost[0]) >= 2
    if have_cost:
        spans.append(ms(cost[0]))
    if in_use is not None:
        spans.append(ms([in_use - 0.01, in_use + 0.01]))
    lo, hi = min(float(np.min(s)) for s in spans), max(float(np.max(s)) for s in spans)
    pad = 0.05 * (hi - lo)
    lo, hi = lo - pad, hi + pad
    with _style():
        fig = figure(*size)
        rows = 2 if have_cost else 1
        axes = [fig.add_subplot(rows, 1, k + 1) for k in range(rows)]
        if have_cost:
            ax = axes[0]
            x, y = ms(cost[0]), np.degrees(np.asarray(cost[1], dtype=float))
            order = np.argsort(x)
            ax.plot(x[order], y[order], "o-", color=_GOOD, ms=5,
                    label="RMS of the marker bearings' residuals (boresight refitted at each offset)")
            ax.axvspan(ms(best.offset - best.sigma), ms(best.offset + best.sigma), color=_GOOD, alpha=0.3, lw=0)
            ax.axvline(ms(best.offset), color=_GOOD, lw=1.5,
                       label=f"the marker bearings' best: {ms(best.offset):.1f} ± {ms(best.sigma):.1f} ms")
            ax.set_ylabel("residual RMS [deg]")
            ax.set_title("the marker bearings against the time offset: the lower, the better they agree", loc="left")
        ax = axes[-1]
        sel = (ms(coarse.taus) >= lo) & (ms(coarse.taus) <= hi)
        if np.any(sel):
            ax.plot(ms(coarse.taus)[sel], np.degrees(coarse.curve)[sel] if scan else np.asarray(coarse.curve)[sel],
                    "o-" if scan else "-", color="0.35", ms=3,
                    label="RMS of the marker bearings' residuals (capped), over the whole search" if scan else
                    "phase coherence of the VO heading and the track direction")
        for a in axes:
            a.axvspan(ms(coarse.offset - coarse.sigma), ms(coarse.offset + coarse.sigma), color="0.6", alpha=0.25,
                      lw=0, label=f"{'the marker scan' if scan else 'the VO heading alone'}: "
                                  f"{ms(coarse.offset):.1f} ± {ms(coarse.sigma):.1f} ms")
            if in_use is not None:
                a.axvline(ms(in_use), color=_BAD if off else "k", lw=2.5, ls="--",
                          label=f"in use by this run: {ms(in_use):.1f} ms")
            a.set_xlim(lo, hi)
            a.grid(True, alpha=0.3)
        if baseline is not None and lo <= ms(baseline.offset) <= hi:
            ax.axvline(ms(baseline.offset), color="C2", ls=":", lw=2,
                       label=f"the paper's cross-correlation: {ms(baseline.offset):.0f} ms (one-frame steps)")
        ax.set_ylabel("residual RMS [deg]" if scan else "coherence (1: follows)")
        ax.ticklabel_format(axis="y", style="plain", useOffset=False)
        ax.set_title("context: the marker bearings over the whole search (the VO heading gave none)" if scan else
                     "context: the coarse estimate from the VO heading (coherence: the higher, the better)", loc="left")
        ax.set_xlabel("time offset: camera stamp − total-station time [ms]")
        for a in axes:
            a.legend(loc="best", fontsize=9.5)
        return _finish(fig, path, answer)


# --------------------------------------------------------------------------- markers


def plot_marker_agreement(path: str, agreement, pairwise=None, size: Optional[Tuple[int, int]] = None) -> str:
    """Do the markers agree? One lane per marker: each of its yaws' deviation from the frame's consensus (the
    filtered heading), its median and robust spread, the observations the pipeline rejected marked with their
    most common reason; a flagged marker's lane in red and named in the title. Right: the pairwise differences
    as a matrix (mean of row − column in the same image, degrees). ``agreement``: an
    ``evaluation.MarkerAgreement``; ``pairwise``: ``evaluation.PairwiseDifferences`` or None."""
    ids = list(agreement.markers)
    m = len(ids)
    size = size or (WIDTH, max(380, 160 + 55 * m))
    flagged = set(agreement.flagged)
    answer = _agreement_answer(agreement, ids, flagged)
    ok = np.isfinite(agreement.median)
    finite = np.degrees(np.abs(agreement.median[ok]) + np.nan_to_num(agreement.spread[ok]))
    typical = math.degrees(agreement.typical_spread) if math.isfinite(agreement.typical_spread) else 0.05
    lim = max(6.0 * typical, 1.1 * float(finite.max()) if finite.size else 0.0, 0.05)
    with _style():
        fig = figure(*size)
        height = size[1]
        top = 1.0 - _title(fig, answer) - 34.0 / height            # the legend's row under the title
        bottom = 66.0 / height
        ax = fig.add_axes([0.12, bottom, 0.4, top - bottom])
        dev = np.degrees(agreement.deviation)
        rng = np.random.RandomState(0)
        for k, mid in enumerate(ids):
            sel = (agreement.ids == mid) & np.isfinite(dev)
            y = k + rng.uniform(-0.22, 0.22, int(sel.sum()))
            d = dev[sel]
            acc = agreement.accepted[sel]
            inside = np.abs(d) <= lim
            bad = mid in flagged
            if bad:
                ax.axhspan(k - 0.45, k + 0.45, color=_BAD, alpha=0.12, lw=0)
            ax.plot(d[acc & inside], y[acc & inside], ".", color=_GOOD, ms=4, alpha=0.6)
            ax.plot(d[~acc & inside], y[~acc & inside], "x", color=_BAD, ms=5, alpha=0.8)
            for side, marker in ((-1.0, "<"), (1.0, ">")):     # beyond the axis: at its edge, pointing out
                out = side * d > lim
                ax.plot(np.full(int(out.sum()), side * lim * 0.985), y[out], marker, ms=5,
                        color=_BAD if bad else "0.3")
            med, spread = math.degrees(agreement.median[k]), math.degrees(agreement.spread[k])
            if math.isfinite(med):
                ax.add_patch(_rectangle((med - spread, k - 0.3), 2 * spread, 0.6))
                ax.plot([med, med], [k - 0.35, k + 0.35], "-", color="k", lw=2.5)
            reasons = agreement.rejected.get(mid, {})
            text = f"{med:+.3f}° ± {spread:.3f}°" if math.isfinite(med) else "no consensus"
            if reasons:
                reason, _ = Counter(reasons).most_common(1)[0]
                text += f"\n{sum(reasons.values())} rejected: {_short(reason, 26)}" + (" …" if len(reasons) > 1 else "")
            ax.text(1.02, k, text, transform=ax.get_yaxis_transform(), va="center", fontsize=9.5,
                    color=_BAD if bad else "k")
        ax.set_yticks(range(m))
        ax.set_yticklabels([f"marker {i}\n({int(n)} seen)" for i, n in zip(ids, agreement.n)], fontsize=10)
        ax.set_ylim(m - 0.5, -0.5)
        ax.set_xlim(-lim, lim)
        ax.axvline(0.0, color="k", lw=0.8)
        ax.set_xlabel("yaw − the frame's consensus (the filtered heading) [deg]")
        ax.grid(True, axis="x", alpha=0.3)
        ax.plot([], [], ".", color=_GOOD, label="accepted")
        ax.plot([], [], "x", color=_BAD, label="rejected (why: at the right)")
        ax.plot([], [], "s", color="0.75", label="median ± robust spread")
        ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=3, fontsize=9.5, frameon=False)
        if pairwise is not None and pairwise.per_pair:
            side = min(0.15 * size[0], (top - bottom) * height - 30.0)
            _pair_matrix(fig.add_axes([0.83, bottom, side / size[0], side / height]), pairwise, lim)
        return save_figure(fig, path, answer)


def _agreement_answer(agreement, ids, flagged) -> str:
    """The title of :func:`plot_marker_agreement`: the markers that disagree and by how much, or how well all agree."""
    if flagged:
        by = ", ".join(f"marker {i} by {math.degrees(agreement.median[ids.index(i)]):+.3f}°"
                       for i in sorted(flagged, key=lambda i: -abs(agreement.median[ids.index(i)])))
        names = ", ".join(str(i) for i in sorted(flagged))
        typical = _deg(agreement.typical_spread)
        if len(flagged) == 1:
            off = math.degrees(agreement.median[ids.index(min(flagged))])
            return (f"marker {names} disagrees with the others by {off:+.3f}° (their typical spread {typical}): "
                    "moved, or surveyed wrong")
        return f"markers {names} disagree with the others: {by} (their typical spread {typical}): moved, or " \
               "surveyed wrong"
    if ids:
        worst = float(np.nanmax(np.abs(agreement.median))) if np.any(np.isfinite(agreement.median)) else float("nan")
        return (f"the markers agree: every marker's median within {_deg(worst)} of the consensus, typical spread "
                f"{_deg(agreement.typical_spread)}")
    return "no marker yaw had a consensus to compare with (the filter never ran)"


def _short(reason: str, most: int = 32) -> str:
    """A pipeline rejection reason without its explanation (in brackets, or after the colon of a long one), at most
    ``most`` characters."""
    text = reason.split(" (")[0]
    if len(text) > most and ": " in text:
        text = text.split(": ")[0]
    return text if len(text) <= most else text[:most - 1] + "…"


def _rectangle(xy, width, height):
    from matplotlib.patches import Rectangle

    return Rectangle(xy, width, height, facecolor="0.75", edgecolor="0.4", alpha=0.7, zorder=1)


def _pair_matrix(ax, pairwise, lim: float) -> None:
    """The pairs' mean differences (row − column, degrees) as a matrix, annotated while it stays readable."""
    ids = sorted({i for pair in pairwise.per_pair for i in pair})
    n = len(ids)
    mat = np.full((n, n), np.nan)
    for (a, b), st in pairwise.per_pair.items():
        mat[ids.index(a), ids.index(b)] = math.degrees(st.bias)
        mat[ids.index(b), ids.index(a)] = -math.degrees(st.bias)
    ax.imshow(np.ma.masked_invalid(mat), cmap="coolwarm", vmin=-lim, vmax=lim)
    if n <= 10:
        for i in range(n):
            for j in range(n):
                if np.isfinite(mat[i, j]):
                    ax.text(j, i, f"{mat[i, j]:+.2f}", ha="center", va="center", fontsize=8 if n > 5 else 9.5)
    ax.set_xticks(range(n))
    ax.set_yticks(range(n))
    ax.set_xticklabels([str(i) for i in ids], fontsize=9)
    ax.set_yticklabels([str(i) for i in ids], fontsize=9)
    ax.set_title("pairs: row − column\n(mean, same image) [deg]", fontsize=10)


# --------------------------------------------------------------------------- heading error


class HeadingCurve(NamedTuple):
    """One heading compared with the reference: ``errors`` (``evaluation.YawErrors``), the estimator's own 1-σ
    (rad) at ``errors.t`` (None: unknown), drawn as ±2σ around zero."""

    label: str
    errors: object
    sigma: Optional[np.ndarray] = None


class Span(NamedTuple):
    """A stretch of the recording (s, same clock as the errors) without absolute updates, and why."""

    start: float
    end: float
    reason: str


def _broken(t: np.ndarray, y: np.ndarray, gap: float) -> Tuple[np.ndarray, np.ndarray]:
    """(t, y) with a NaN inserted wherever consecutive stamps are more than ``gap`` s apart (a line breaks)."""
    if len(t) < 2:
        return t, y
    cut = np.flatnonzero(np.diff(t) > gap) + 1
    return np.insert(t, cut, np.nan), np.insert(y, cut, np.nan)


def plot_heading_error(path: str, curves: Sequence[HeadingCurve], spans: Sequence[Span] = (),
                       rejected: Sequence[Tuple[float, str]] = (), t0: float = 0.0,
                       size: Tuple[int, int] = (WIDTH, 600)) -> str:
    """Is the heading right, and does the filter know how right? Each curve's error (deg) over time (s since
    ``t0``) with its own ±2σ band; ``spans`` without absolute updates shaded with their reason; ``rejected``
    (time s, reason) marker yaws as ticks along the bottom. The title gives RMSE, p95 and the share of the
    errors within the curve's own ±2σ."""
    parts = []
    for k, c in enumerate(curves):
        st = c.errors.stats
        text = f"{'' if k == 0 else c.label + ' '}RMSE {_deg(st.rmse)}, p95 {_deg(st.p95)}"
        if c.sigma is not None and len(c.sigma) == len(c.errors.error):
            ok = np.isfinite(c.sigma)
            if np.any(ok):
                inside = np.mean(np.abs(c.errors.error[ok]) <= 2.0 * c.sigma[ok])
                whose = "the filter's" if k == 0 else "its"
                text += f", {100 * inside:.0f} % within {whose} own ±2σ"
        parts.append(text)
    answer = "heading error " + "; ".join(parts) if parts else "no heading to compare with the reference"
    colours = [_GOOD, "#d35400", "#7f3c8d"]
    span_colours = ["#f1c40f", "#95a5a6", "#9b59b6", "#e67e22", "#16a085"]
    with _style():
        fig = figure(*size)
        ax = fig.add_subplot(1, 1, 1)
        reasons = list(dict.fromkeys(s.reason for s in spans))
        for s in spans:
            c = span_colours[reasons.index(s.reason) % len(span_colours)]
            ax.axvspan(s.start - t0, s.end - t0, color=c, alpha=0.25, lw=0)
        for r in reasons:
            ax.fill_between([], [], [], color=span_colours[reasons.index(r) % len(span_colours)], alpha=0.25,
                            label=f"no absolute update: {_short(r, 40)}")
        for k, c in enumerate(curves):
            colour = colours[k % len(colours)]
            t = np.asarray(c.errors.t, dtype=float) - t0
            if c.sigma is not None and len(c.sigma) == len(t):
                tb, sb = _broken(t, 2.0 * np.degrees(np.asarray(c.sigma, dtype=float)), 0.5)
                ax.fill_between(tb, -sb, sb, color=colour, alpha=0.15, lw=0, label=f"{c.label}: its own ±2σ")
            tl, el = _broken(t, np.degrees(c.errors.error), 0.5)
            ax.plot(tl, el, color=colour, lw=1.6 if k == 0 else 1.3, ls="-" if k == 0 else "--",
                    label=f"{c.label} (RMSE {_deg(c.errors.stats.rmse)})")
        if len(rejected):
            by_reason = Counter(r for _, r in rejected)
            for j, (r, _) in enumerate(by_reason.most_common(3)):
                ts = [t - t0 for t, why in rejected if why == r]
                ax.plot(ts, np.full(len(ts), 0.02 + 0.035 * j), "|", ms=10, mew=1.5, color=_BAD,
                        alpha=1.0 - 0.25 * j, transform=ax.get_xaxis_transform(),
                        label=f"rejected marker yaw: {_short(r)} ({by_reason[r]})")
        ax.axhline(0.0, color="k", lw=0.6)
        shown = [np.abs(np.degrees(c.errors.error)) for c in curves if len(c.errors.error)]
        if curves and curves[0].sigma is not None and len(curves[0].sigma):
            shown.append(2.0 * np.degrees(np.asarray(curves[0].sigma, dtype=float)))
        finite = np.concatenate(shown) if shown else np.zeros(0)
        finite = finite[np.isfinite(finite)]
        if finite.size:   # the errors and the first curve's band decide the scale; a wider band is cut off
            lim = 1.15 * max(float(np.percentile(finite, 99.5)), 0.01)
            ax.set_ylim(-lim, lim)
        ax.set_xlabel("time since the start of the recording [s]")
        ax.set_ylabel("heading − reference [deg]")
        ax.grid(True, alpha=0.3)
        top = 1.0 - _title(fig, answer)
        handles = ax.get_legend_handles_labels()[0]
        rows = (len(handles) + 1) // 2
        bottom = (60.0 + 21.0 * rows) / size[1]
        if handles:
            ax.legend(loc="upper center", bbox_to_anchor=(0.5, -56.0 / (size[1] * (top - bottom))), ncol=2,
                      fontsize=9.5, frameon=False)
        fig.subplots_adjust(left=0.08, right=0.98, top=top - 0.02, bottom=bottom)
        return save_figure(fig, path, answer)


# --------------------------------------------------------------------------- position in the frame


def plot_frame_position(path: str, bias, size: Tuple[int, int] = (WIDTH, 520)) -> str:
    """Does the yaw error depend on where the marker is in the frame (paper fig. 13)? A heatmap of the mean
    signed yaw error (deg) over azimuth × elevation; bins with fewer than ``bias.min_count`` samples blank."""
    shown = np.where(bias.count >= bias.min_count, np.degrees(bias.mean), np.nan)
    finite = shown[np.isfinite(shown)]
    answer = (f"yaw error by position in the frame: the largest bin mean is {_deg(bias.max_abs_bias)} "
              f"(bins of at least {bias.min_count} observations)" if finite.size
              else "yaw error by position in the frame: no bin has enough observations")
    lim = max(float(np.max(np.abs(finite))) if finite.size else 0.0, 0.05)
    with _style():
        fig = figure(*size)
        ax = fig.add_subplot(1, 1, 1)
        mesh = ax.pcolormesh(np.degrees(bias.az_edges), np.degrees(bias.el_edges), np.ma.masked_invalid(shown),
                             cmap="coolwarm", vmin=-lim, vmax=lim)
        fig.colorbar(mesh, ax=ax, label="mean yaw error [deg]")
        ax.set_xlabel("azimuth in the frame [deg] (0 = image centre, + = left)")
        ax.set_ylabel("elevation [deg]")
        ax.invert_xaxis()  # as in the image: azimuth grows to the left
        return _finish(fig, path, answer)


# --------------------------------------------------------------------------- calibration


def _binned_median(x: np.ndarray, y: np.ndarray, edges: np.ndarray, min_count: int = 3):
    """(bin centres, medians) of ``y`` in the bins of ``x`` (``edges``); NaN (a line breaks there) in a bin with
    fewer than ``min_count`` samples."""
    centres = 0.5 * (edges[:-1] + edges[1:])
    medians = np.full(len(centres), np.nan)
    for k, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        sel = (x >= a) & (x < b) & np.isfinite(y)
        if np.count_nonzero(sel) >= min_count:
            medians[k] = float(np.median(y[sel]))
    return centres, medians


def mounting_turn(rpy, bearings: np.ndarray, base_R_camera: np.ndarray) -> np.ndarray:
    """The angle (rad, (N,)) by which a boresight ``rpy`` (roll, pitch, yaw rad, in base_link on top of the
    mounting ``base_R_camera``) turns each camera-frame unit bearing (N, 3): what a camera mounted that far off
    shows as bearing residuals under its nominal mounting."""
    R = np.asarray(base_R_camera, dtype=float)
    w = bearings @ (R.T @ rpy_to_matrix(*rpy) @ R).T
    return np.arccos(np.clip(np.sum(w * bearings, axis=1), -1.0, 1.0))


def calibration_answer(cal) -> str:
    """The calibration figure's title: how far the mounting was off, and the residuals before and after."""
    rpy = np.degrees(np.asarray(cal.boresight_rpy, dtype=float))
    sd = np.degrees(np.asarray(cal.boresight_sigma, dtype=float))
    angle = math.degrees(float(np.linalg.norm(cal.boresight_rpy)))
    parts = ", ".join(f"{name} {v:+.2f}° ± {s:.2f}°" for name, v, s in zip(("roll", "pitch", "yaw"), rpy, sd))
    before, after = _deg(cal.residual_rms_before), _deg(cal.residual_rms_after)
    if np.all(np.abs(rpy) <= 2.0 * sd):
        return (f"camera mounted as the lever arms say: no turn beyond 2σ ({parts}); bearing residuals {before} → "
                f"{after} RMS")
    return f"camera mounting off by {angle:.2f}° ({parts}): bearing residuals {before} → {after} RMS after calibrating"


def plot_calibration(path: str, cal, bearings, base_R_camera=None, size: Tuple[int, int] = (WIDTH, 720)) -> str:
    """Was the camera mounted as the lever arms say? The bearing residuals (deg) of the observations calibrate
    kept, against azimuth (left) and elevation (right), before (the nominal mounting, top) and after (the fitted
    one, bottom), per lens side (front, back), with their binned medians; on top, the turn the fitted mounting
    gives each bearing (:func:`mounting_turn`, its σ in the title): a tilted camera shows as residuals that
    rise and fall with azimuth before and vanish after. ``cal``: a ``calibration.Calibration``; ``bearings``
    (N, 3): its observations' camera-frame bearings; ``base_R_camera``: the nominal mounting (default level)."""
    b = np.asarray(bearings, dtype=float).reshape(-1, 3)
    used = np.asarray(cal.used, dtype=bool)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    az, el = (np.degrees(a) for a in bearing_to_azel(b))
    front = cal.lenses.front_weight(b) >= 0.5
    R = np.eye(3) if base_R_camera is None else np.asarray(base_R_camera, dtype=float)[:3, :3]
    model = np.degrees(mounting_turn(cal.boresight_rpy, b[used], R))
    answer = calibration_answer(cal)
    before, after = np.degrees(cal.residuals_before), np.degrees(cal.residuals_after)
    top = float(np.nanpercentile(before[used], 98)) if np.any(used) else 0.1
    top = max(top, float(np.max(model)) if model.size else 0.0) * 1.15 + 1e-3
    with _style():
        fig = figure(*size)
        axes = [[fig.add_subplot(2, 2, 2 * r + c + 1) for c in range(2)] for r in range(2)]
        for c, (x, edges, label) in enumerate(((az, np.arange(-180.0, 181.0, 20.0), "azimuth in the frame [deg]"),
                                               (el, np.linspace(np.min(el[used]) if np.any(used) else -30.0,
                                                                np.max(el[used]) + 1e-6 if np.any(used) else 30.0, 9),
                                                "elevation [deg]"))):
            for r, (res, when) in enumerate(((before, "before: the nominal mounting"),
                                             (after, "after: the fitted mounting"))):
                ax = axes[r][c]
                for lens, sel, colour in (("front lens", front, _GOOD), ("back lens", ~front, "#d35400")):
                    s = used & sel
                    if not np.any(s):
                        continue
                    ax.plot(x[s], res[s], ".", ms=3, alpha=0.35, color=colour)
                    cx, my = _binned_median(x[s], res[s], edges)
                    ax.plot(cx, my, "-o", ms=4, lw=2, color=colour, label=f"{lens}: median ({int(s.sum())})")
                if r == 0:
                    cx, my = _binned_median(x[used], model, edges)
                    ax.plot(cx, my, "k--", lw=1.8, label="the turn of the fitted mounting")
                ax.set_ylim(0.0, top)
                ax.grid(True, alpha=0.3)
                ax.set_title(when, loc="left", fontsize=11)
                if c == 0:
                    ax.set_ylabel("bearing residual [deg]")
                if r == 1:
                    ax.set_xlabel(label)
                if r == 0 and c == 0:
                    ax.legend(loc="upper right", fontsize=9)
        return _finish(fig, path, answer)


# --------------------------------------------------------------------------- overview


def _status_colour(status: str) -> str:
    return "#27ae60" if status == "found" else "#e67e22" if status.startswith("found") else _BAD


def plot_overview(path: str, grey: np.ndarray, found, expected, trajectory, marker_xy: Mapping[int, np.ndarray],
                  where: Optional[np.ndarray] = None, reference_xy: Optional[np.ndarray] = None,
                  headline: str = "", size: Tuple[int, int] = (WIDTH, 1000)) -> str:
    """What did the camera see, and where was the platform? Above, a 360° frame with the markers found outlined
    (``found``: observations with ``corners_px``, ``pixel``, ``id``) and the map's markers where they should be
    (``expected``: ``debugview.ExpectedMarker``), each one missed or not used marked with why; below, the
    corrected trajectory (``trajectory``: positions (N, 2) m and yaws (N,) rad) with its heading as arrows, the
    markers (``marker_xy``: id → (2,) m) in the colours of the frame, the reference (``reference_xy``) and where
    the frame was taken (``where`` (2,)) with sight lines to the markers. ``headline``: the title's answer."""
    import cv2

    positions, yaws = trajectory
    h, w = grey.shape[:2]
    shown = min(w, int(0.98 * size[0]))                # the axes' pixels: drawn 1:1, no aliasing
    small = cv2.resize(grey, (shown, shown * h // w), interpolation=cv2.INTER_AREA) if shown != w else grey
    with _style():
        fig = figure(*size)
        top = 1.0 - _title(fig, headline)
        frame_h = 0.98 * size[0] * h / w / size[1]
        ax = fig.add_axes([0.01, top - 0.035 - frame_h, 0.98, frame_h])
        ax.imshow(small, cmap="gray", vmin=0, vmax=255, extent=(0, w, h, 0))
        labels = []                                     # (u, v, text, colour) of what was not found or not used
        for e in expected:
            colour = _status_colour(e.status)
            ax.plot([e.u], [e.v], "o", ms=15, mfc="none", mec=colour, mew=2)
            if e.status != "found":
                labels.append((e.u, e.v, f"{e.id}: {e.status}", colour))
        rows: list = []                                 # stacked above the markers, never overlapping
        base = min((v for _, v, _, _ in labels), default=0.0) - 0.05 * h
        for u, v, text, colour in sorted(labels):
            width = 0.0105 * w * len(text)                # data px of the text at 9 pt
            left = u - width if u > 0.7 * w else u
            row = next((k for k, end in enumerate(rows) if end < left), len(rows))
            rows[row:row + 1] = [left + width]
            ax.annotate(text, (u, v), xytext=(u, base - 0.05 * h * row), textcoords="data",
                        ha="right" if u > 0.7 * w else "left", fontsize=9, color="white",
                        arrowprops={"arrowstyle": "-", "color": colour, "lw": 1},
                        bbox={"facecolor": colour, "alpha": 0.9, "pad": 1.5, "lw": 0})
        for o in found:
            u, v = o.corners_px[:, 0], o.corners_px[:, 1]
            ax.plot(np.append(u, u[0]), np.append(v, v[0]), "-", color="#2ecc71", lw=2)
            ax.annotate(f"{o.id}", (o.pixel[0], o.pixel[1]), xytext=(0, -20), textcoords="offset points",
                        ha="center", fontsize=10, color="black",
                        bbox={"facecolor": "#2ecc71", "alpha": 0.85, "pad": 1.5, "lw": 0})
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        ax.set_axis_off()
        ax.set_title("outlined: found in the frame; circles: where the map puts each marker (green: used; orange: "
                     "found, not used; red: not found) and why", fontsize=10)
        ax2 = fig.add_axes([0.09, 0.06, 0.88, top - 0.13 - frame_h])
        if reference_xy is not None and len(reference_xy):
            ax2.plot(reference_xy[:, 0], reference_xy[:, 1], "-", color="0.7", lw=5, label="reference")
        xy = np.array(list(marker_xy.values()) + list(positions), dtype=float).reshape(-1, 2)
        extent = float(np.max(np.ptp(xy, axis=0))) if len(xy) > 1 else 1.0
        if len(positions):
            ax2.plot(positions[:, 0], positions[:, 1], "-", color=_GOOD, lw=1.5, label="corrected base_link")
            step = max(len(positions) // 12, 1)
            length = 0.05 * max(extent, 1.0)
            p, y = positions[::step], yaws[::step]
            ax2.quiver(p[:, 0], p[:, 1], length * np.cos(y), length * np.sin(y), angles="xy", scale_units="xy",
                       scale=1.0, width=0.005, headwidth=4, headlength=5, color=_GOOD, label="its heading")
        by_id = {e.id: e for e in expected}
        for mid, m_xy in marker_xy.items():
            e = by_id.get(mid)
            colour = "k" if e is None else _status_colour(e.status)
            ax2.plot(m_xy[0], m_xy[1], "s", color=colour, ms=8)
            ax2.annotate(str(mid), m_xy, xytext=(5, 5), textcoords="offset points", fontsize=10)
            if where is not None and e is not None:
                ax2.plot([where[0], m_xy[0]], [where[1], m_xy[1]], "-" if e.status == "found" else ":",
                         color=colour, lw=1)
        if where is not None:
            ax2.plot(where[0], where[1], "*", color="k", ms=18, label="where the frame above was taken")
        ax2.set_aspect("equal", adjustable="datalim")
        ax2.set_xlabel("map x [m]")
        ax2.set_ylabel("map y [m]")
        ax2.grid(True, alpha=0.3)
        ax2.legend(loc="best", fontsize=9.5)
        return save_figure(fig, path, headline)
