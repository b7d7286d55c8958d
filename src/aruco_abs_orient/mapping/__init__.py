"""The marker map from a recording: the markers surveyed by the platform itself, not by the total station.

In: a recording's marker bearings (every id seen, with their corners), its odometry, its prism track and the
camera's mounting and lenses as known; optionally control markers (surveyed) and which camera parameters to
estimate too. Out: each marker's centre in the total station's frame with its covariance (3-σ ellipsoid), face
normal with its σ, the redundancy of its observations and its test against the others (``network``, ``faces``);
markers seen too little refused with what to drive, markers that disagree left out with their residual; the
markers YAML that ``process``, ``calibrate`` and the node read, a report, and the comparison of two maps
(``output``, ``compare``). The observation model and the least squares are the calibration's, with the markers
free (``calibration.problem``, ``calibration.solve``).
"""

from .model import MappedMarker, MappingError, MappingParams, MappingResult, MapUnknowns
from .network import map_markers

__all__ = ["MappedMarker", "MappingError", "MappingParams", "MappingResult", "MapUnknowns", "map_markers"]
