"""Two marker maps compared: which markers moved between two recordings (or since their survey) beyond their σ.

In: the new and the old map (``markers.MarkerMap``: a map ``map`` wrote carries each marker's covariance, a
surveyed one its σ in every direction), both in the total station's frame, and the test's false-alarm rate. Out:
:class:`Comparison`: per marker in both, its shift (m), its normalised size (√χ² of 3 degrees of freedom against
the sum of both covariances) and whether it moved; the ids in one map only; :meth:`Comparison.lines` for people.
A knocked marker is the commonest failure on a site: a shift of a few σ is found whatever its direction.
"""

from __future__ import annotations

import math
from typing import List, NamedTuple

import numpy as np

from ..markers import Marker, MarkerMap
from .model import chi2_quantile

__all__ = ["MarkerMove", "Comparison", "compare_maps"]


class MarkerMove(NamedTuple):
    """One marker in both maps: ``shift`` (3,) m new − old, its length ``distance`` (m), ``chi`` = √(shiftᵀ (C_new
    + C_old)⁻¹ shift), ``moved`` when χ² exceeds the limit."""

    id: int
    shift: np.ndarray
    distance: float
    chi: float
    moved: bool


class Comparison(NamedTuple):
    """``moves`` (every marker in both maps, by id), ``only_new`` / ``only_old`` ids, ``limit`` the √χ² a move
    is held to."""

    moves: List[MarkerMove]
    only_new: List[int]
    only_old: List[int]
    limit: float

    @property
    def moved(self) -> List[MarkerMove]:
        return [m for m in self.moves if m.moved]

    def lines(self, old_name: str = "the old map") -> List[str]:
        """What a surveyor reads: the markers that moved (mm, direction, σ), then a summary."""
        out = []
        for m in self.moved:
            dx, dy, dz = 1e3 * m.shift
            out.append(f"marker {m.id} moved {1e3 * m.distance:.1f} mm (x {dx:+.1f}, y {dy:+.1f}, z {dz:+.1f} mm; "
                       f"{m.chi:.1f} σ, limit {self.limit:.1f}) since {old_name}: re-survey it or put it back")
        if len(self.moves) >= 3 and len(self.moved) > len(self.moves) // 2:
            out.append(f"{len(self.moved)} of {len(self.moves)} markers moved: more likely the total station's set-up "
                       "differs between the recordings than the markers (check the station and its orientation)")
        out.append(f"compared with {old_name}: {len(self.moves)} markers in both, {len(self.moved)} moved beyond their "
                   f"σ" + (f"; only in the new map: {', '.join(map(str, self.only_new))}" if self.only_new else "")
                   + (f"; only in {old_name}: {', '.join(map(str, self.only_old))}" if self.only_old else ""))
        return out


def _cov(m: Marker) -> np.ndarray:
    return m.covariance if m.covariance is not None else m.sigma ** 2 * np.eye(3)


def compare_maps(new: MarkerMap, old: MarkerMap, alpha: float = 0.001) -> Comparison:
    """Each marker of both maps tested for a move: χ² of its shift against both covariances, 3 degrees of freedom,
    false-alarm rate ``alpha``. Positions are compared as the maps hold them (relative to their origins; the
    origins must agree)."""
    shift0 = (np.zeros(3) if new.origin is None else new.origin) - (np.zeros(3) if old.origin is None else old.origin)
    limit = chi2_quantile(3.0, alpha)
    moves = []
    for mid in sorted(set(new.ids) & set(old.ids)):
        a, b = new[mid], old[mid]
        d = a.position - b.position + shift0
        chi2 = float(d @ np.linalg.solve(_cov(a) + _cov(b), d))
        moves.append(MarkerMove(mid, d, float(np.linalg.norm(d)), math.sqrt(chi2), chi2 > limit))
    return Comparison(moves, sorted(set(new.ids) - set(old.ids)), sorted(set(old.ids) - set(new.ids)),
                      math.sqrt(limit))
