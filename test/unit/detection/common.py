"""Helpers shared by the detection tests: truth from the rendered markers, one detector."""
import math
import os
from functools import lru_cache

import numpy as np

from aruco_abs_orient.camera import angle_between
from aruco_abs_orient.detection import MarkerDetector

SRC = os.path.join(os.path.dirname(__file__), "..", "..", "..", "src")
DEG = math.pi / 180.0


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def true_centre(m):
    return unit(m.center)


def err_deg(obs, m):
    return float(angle_between(obs.centre, true_centre(m))) / DEG


def by_id(observations):
    return {o.id: o for o in observations}


@lru_cache(maxsize=None)
def detector():
    return MarkerDetector("DICT_4X4_50")
