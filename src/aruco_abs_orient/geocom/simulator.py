"""A simulated Leica MS60 (or TPS1200) speaking ASCII GeoCOM, on a pty or on TCP (127.0.0.1 only).

In: a :class:`~.instrument.SimConfig` (profile, model, link timing, faults, accuracy), a prism track
and a seed. Out: a GeoCOM instrument a client reaches at :meth:`Ms60Simulator.serve_pty`'s path or
:meth:`Ms60Simulator.serve_tcp`'s port, and the truth log of every coordinate it reported.
Contract: the ``strict`` profile (default) behaves like the instruments of the TPS1200+/Captivate
GeoCOM references (checked parameters, TPS1200+ measurement programs only, station changes refused
while a distance exists, LOCK mode and a fine adjustment before lock-in, motors and EDM that take
their time); ``lenient`` is a forgiving instrument (instant lock-in, a fresh distance every poll).
The ``TPS1200`` model has no PowerSearch and refuses the fast and synchro tracking programs.
The parts: :mod:`.instrument` (the model), :mod:`.dispatch` (GeoCOM), :mod:`.transport` (the link).
"""

from __future__ import annotations

from typing import Callable, List, Optional

import numpy as np

from .dispatch import GeoComDispatcher
from .instrument import FaultRates, Ms60Instrument, SimConfig, builtin_track
from .transport import GeoComServer

__all__ = ["Ms60Simulator", "FaultRates", "SimConfig", "builtin_track"]


class Ms60Simulator(Ms60Instrument):
    """The instrument (its state, :attr:`truth` and :attr:`events`) answering GeoCOM through
    :attr:`dispatcher` on :attr:`server`'s link. Start it with :meth:`serve_pty` or :meth:`serve_tcp`;
    stop with :meth:`close`."""

    def __init__(self, config: Optional[SimConfig] = None, track: Callable[[float], np.ndarray] = builtin_track,
                 seed: Optional[int] = None):
        super().__init__(config, track, seed)
        self.dispatcher = GeoComDispatcher(self)
        self.server = GeoComServer(self.dispatcher)

    @property
    def requests(self) -> int:
        """GeoCOM requests received so far."""
        return self.dispatcher.requests

    @property
    def internal_errors(self) -> List[str]:
        """Exceptions raised inside procedures (each answered with UNDEFINED); empty unless the simulator has a bug."""
        return self.dispatcher.internal_errors

    def serve_pty(self) -> str:
        """Serve on a new pseudo-terminal; returns the path of the "serial port" a client opens."""
        return self.server.serve_pty()

    def serve_tcp(self, port: int = 0) -> int:
        """Serve on TCP 127.0.0.1:``port`` (0 = any free port); returns the port."""
        return self.server.serve_tcp(port)

    def link_down(self, duration_s: float) -> None:
        """Break the link for ``duration_s`` seconds (TCP: close and refuse; pty: silence)."""
        self.server.link_down(duration_s)

    def close(self) -> None:
        """Stop serving and release the pty/socket."""
        self.server.close()
