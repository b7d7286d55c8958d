"""ArUco detection in 360° frames (being split into one module per stage)."""
from .detector import *  # noqa: F403
from .detector import __all__  # noqa: F401
