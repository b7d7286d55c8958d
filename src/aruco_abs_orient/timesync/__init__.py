"""Time offset between the camera and the total station (being split into one module per stage)."""
from .coherence import *  # noqa: F403
from .coherence import __all__  # noqa: F401
