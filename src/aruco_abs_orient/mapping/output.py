"""The mapping's result for the rest of the workflow and for the surveyor: the markers YAML, the report, the plan.

In: a :class:`~.model.MappingResult`, the markers' side, dictionary and frame (and the origin of a national
grid). Out: :func:`mapped_map` (the markers placed, as the ``markers.MarkerMap`` that ``process``,
``calibrate`` and the node read: each with its covariance and, as ``sigma``, the 1-σ of its worst axis),
:func:`mapped_yaml` (that map's YAML with, per marker, its σ, 3-σ ellipsoid, normal σ, views, baseline,
ranges, redundancy and test; refused and left-out markers in its header), :func:`report_markdown` and
:func:`plot_plan` (the map seen from above: the drive, the markers with their 3-σ ellipses enlarged, the refused
and left-out ones).

Units: metres in the map; millimetres and degrees in the fields and text for people.
"""

from __future__ import annotations

import math
from typing import List, Optional

import numpy as np

from ..markers import Marker, MarkerMap
from .compare import Comparison
from .model import MappedMarker, MappingResult

__all__ = ["mapped_map", "mapped_yaml", "report_markdown", "plot_plan"]


def mapped_map(result: MappingResult, size: float, dictionary: str, frame_id: str = "map", origin=None,
               sizes: Optional[dict] = None) -> MarkerMap:
    """The markers placed (status "mapped") as a marker map: position, ``size`` (or ``sizes[id]``), σ of the
    worst axis, normal where determined, covariance."""
    sizes = sizes or {}
    markers = [Marker(m.id, m.position.copy(), float(sizes.get(m.id, size)),
                      float(math.sqrt(max(np.linalg.eigvalsh(m.cov).max(), 0.0))), m.normal, m.cov.copy())
               for m in result.with_status("mapped")]
    return MarkerMap(markers, dictionary, frame_id, "aruco-abs-orient map", origin)


def _fields(m: MappedMarker, marker_map: MarkerMap) -> dict:
    axes, directions = m.ellipsoid(3.0)
    out = {"sigma_mm": [round(1e3 * float(s), 2) for s in m.sigma],
           "ellipsoid_3sigma_mm": [round(1e3 * float(a), 2) for a in axes],
           "ellipsoid_axes": [[round(float(v), 4) for v in row] for row in directions]}
    if m.normal is not None:
        out["normal_sigma_deg"] = round(math.degrees(m.normal_sigma), 3)
    out.update({"views": int(m.views), "baseline_m": round(m.baseline, 2),
                "range_m": [round(m.ranges[0], 2), round(m.ranges[1], 2)], "redundancy": round(m.redundancy, 1),
                "test": round(m.test, 3)})
    if m.control is not None:
        survey = marker_map.to_full(m.control[0])
        out["control"] = {"survey": [round(float(v), 6) for v in survey],
                          "difference_sigma": round(m.control[1], 2), "used": bool(m.control[2])}
    return out


def mapped_yaml(result: MappingResult, marker_map: MarkerMap, source: str = "") -> str:
    """The YAML of :func:`mapped_map`'s ``marker_map`` with each marker's fields for the surveyor, and a header
    naming the markers not in it and why."""
    import yaml

    data = marker_map.to_dict()
    for item in data["markers"]:
        item.update(_fields(result.markers[item["id"]], marker_map))
    head = [f"# written by aruco-abs-orient map{' from ' + source if source else ''}: "
            f"{len(marker_map)} markers placed in the total station's frame from the recording",
            "# per marker: sigma = 1-sigma of its worst axis (m); covariance_mm2 [xx, xy, xz, yy, yz, zz]; the 3-sigma "
            "ellipsoid's semi-axes (mm) and their directions; views, baseline and ranges it was seen from; the "
            "redundancy of its observations and its test against the others (about 1: it agrees)"]
    for m in result.with_status("refused") + result.with_status("left out"):
        head.append(f"# marker {m.id} {m.status}: {m.reason}")
    return "\n".join(head) + "\n" + yaml.safe_dump(data, sort_keys=False, default_flow_style=None)


def _row(m: MappedMarker) -> str:
    sig = "–" if not np.all(np.isfinite(m.cov)) else " / ".join(f"{1e3 * s:.1f}" for s in m.sigma)
    ell = "–" if not np.all(np.isfinite(m.cov)) else " / ".join(f"{1e3 * a:.1f}" for a in m.ellipsoid(3.0)[0])
    normal = "–" if m.normal is None else f"{math.degrees(m.normal_sigma):.2f}"
    rng = "–" if not np.all(np.isfinite(m.ranges)) else f"{m.ranges[0]:.1f}–{m.ranges[1]:.1f}"
    test = "–" if not math.isfinite(m.test) else f"{m.test:.2f} (≤ {m.test_limit:.2f})"
    note = m.reason
    if m.control is not None:
        note = (f"control: {m.control[1]:.1f} σ from its survey, " + ("used" if m.control[2] else "NOT used")
                + (f"; {note}" if note else ""))
    if m.outliers and m.status == "mapped":
        note = f"{m.outliers} sighting{'s' * (m.outliers > 1)} beyond the gate left out" + (f"; {note}" if note else "")
    return (f"| {m.id} | {m.status} | {m.views} | {rng} | {m.baseline:.1f} | {sig} | {ell} | {normal} | "
            f"{m.redundancy:.0f} | {test} | {note} |")


def report_markdown(result: MappingResult, title: str, plan: Optional[str] = None,
                    comparison: Optional[Comparison] = None, elapsed: Optional[float] = None) -> str:
    """The report: what was placed, refused and left out, the camera parameters estimated, the table per marker
    (how often, from how far and from how long a baseline it was seen; σ; 3-σ ellipsoid; normal σ; redundancy;
    test), the comparison with an older map."""
    mapped, refused, out = (result.with_status(s) for s in ("mapped", "refused", "left out"))
    lines: List[str] = [f"# Marker map: {title}", "",
                        f"{len(mapped)} markers placed, {len(refused)} refused (seen too little), {len(out)} left out "
                        f"(disagree with the others); {result.n_used} of {result.n_observations} sightings used "
                        f"(heading model {result.heading_model})" + (f", {elapsed:.1f} s." if elapsed else "."), ""]
    if mapped:
        worst = max(float(np.sqrt(np.linalg.eigvalsh(m.cov).max())) for m in mapped)
        lines += [f"Position 1-σ of the worst axis: at most {1e3 * worst:.1f} mm; the frame is the total station's "
                  "(the prism track)" + (", tied further by control markers." if any(
                      m.control is not None and m.control[2] for m in mapped) else "."), ""]
    if math.isfinite(result.yaw_walk):
        rate = 60 * math.degrees(result.yaw_drift)
        lines += [f"map→odom's yaw (the odometry's yaw drift, corrected) moved {rate:+.2f}°/min and walked "
                  f"{math.degrees(result.yaw_walk):.3f}°/√s about that rate (estimated with the camera's mounting as "
                  "given; with a calibrated camera, the filter's yaw_random_walk should not be below it).", ""]
    if np.any(np.isfinite(result.boresight_sigma)):
        lines += ["Boresight estimated (deg, on top of the mounting given): " + ", ".join(
            f"{n} {math.degrees(a):+.4f} ± {math.degrees(s):.4f}" for n, a, s in
            zip(("roll", "pitch", "yaw"), result.boresight, result.boresight_sigma)), ""]
    if math.isfinite(result.readout_sigma):
        lines += [f"Rolling-shutter readout estimated: {1e3 * result.readout:.2f} ± "
                  f"{1e3 * result.readout_sigma:.2f} ms", ""]
    if plan:
        lines += [f"![the map from above]({plan})", ""]
    lines += ["| id | status | views | range m | baseline m | σ x/y/z mm | 3-σ ellipsoid mm | normal σ ° | redundancy "
              "| test | note |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    lines += [_row(m) for _, m in sorted(result.markers.items())]
    if result.warnings:
        lines += ["", "Warnings:", ""] + [f"- {w}" for w in result.warnings]
    if comparison is not None:
        lines += ["", "## Compared with the old map", ""] + [f"- {line}" for line in comparison.lines()]
    return "\n".join(lines) + "\n"


def plot_plan(result: MappingResult, path: str, title: str = "") -> str:
    """The map from above (PNG): the drive, each marker placed with its 3-σ ellipse (x, y) enlarged so that the
    largest is visible, refused markers grey, left-out ones red, control markers as triangles."""
    from ..plots import figure, save_figure

    fig = figure(1000, 900)
    ax = fig.add_subplot(1, 1, 1)
    if len(result.drive):
        ax.plot(result.drive[:, 0], result.drive[:, 1], "-", color="0.6", lw=1, label="drive (prism)")
    mapped = result.with_status("mapped")
    semi = [m.ellipsoid(3.0)[0][0] for m in mapped]
    points = np.concatenate([result.drive[:, :2]] + [m.position[None, :2] for m in mapped])
    span = float(np.ptp(points, axis=0).max()) if len(points) else 1.0
    want = 0.05 * span / max(max(semi, default=1e-3), 1e-6)           # the largest ellipse 5 % of the plan
    decade = 10 ** math.floor(math.log10(max(want, 1.0)))
    gain = max(step * decade for step in (1, 2, 5) if step * decade <= max(want, 1.0))
    t = np.linspace(0.0, 2.0 * math.pi, 60)
    for m in result.markers.values():
        if not np.all(np.isfinite(m.position)):
            continue
        x, y = m.position[:2]
        colour = {"mapped": "C0", "refused": "0.5", "left out": "C3"}[m.status]
        ax.plot([x], [y], "^" if m.control is not None else "o", color=colour, ms=5)
        ax.annotate(str(m.id), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8, color=colour)
        if m.status == "mapped":
            w, v = np.linalg.eigh(m.cov[:2, :2])
            e = (v * (3.0 * gain * np.sqrt(np.maximum(w, 0.0)))) @ np.stack([np.cos(t), np.sin(t)])
            ax.plot(x + e[0], y + e[1], "-", color=colour, lw=1)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{title}: 3-σ ellipses ×{gain:g}; grey refused, red left out, ▲ control", fontsize=10)
    ax.grid(True, lw=0.3)
    return save_figure(fig, path)
