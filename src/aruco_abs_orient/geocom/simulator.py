"""A simulated Leica MS60 speaking ASCII GeoCOM, on a pty or on TCP (127.0.0.1 only).

What it models (all times are host ``time.time()`` seconds; the truth log uses them):

- the wire: a request of n bytes is complete ``10·n/baud`` s after its first byte; a reply of m
  bytes leaves ``latency ± jitter`` s after the measurement and takes ``10·m/baud`` s to send;
- the instrument clock: a millisecond counter ``T = floor(((t − t_boot)(1 + drift))·1000 +
  offset_ms) mod wrap_ms``; a TMC_GetCoordinate measures the angles at the next counter tick
  after the request is complete and reports the prism position of that instant (tracking
  mode), with that tick as its time;
- the prism: a TUM trajectory (positions interpolated, looped) or a built-in smooth track;
- lock: AUT_LockIn locks when the prism is visible (rc 0) or fails with 8710 AUT_NO_TARGET;
  while unlocked TMC_GetCoordinate answers 1285 TMC_ANGLE_OK (angles only, no position) and
  MOT_ReadLockStatus 0; after the prism reappears the lock stays out until AUT_LockIn;
- faults: garbage bytes before a reply, dropped replies, late replies (after the client's
  timeout), warnings 1283/1284 (position kept), lost lock for a while, link outages (TCP: the
  connection is closed and refused; pty: the line goes silent), latency spikes.

Every TMC_GetCoordinate answer is logged in :attr:`Ms60Simulator.truth` with the true host time
of its measurement, its instrument time and the true position, so tests can measure errors.

A real instrument keeps its reply timing whatever the host does; the simulator is a host thread
and may wake late to send (a loaded machine). A coordinate reply that would leave more than
``LATE_S`` after its due time is measured again at the next counter tick and sent with the same
latency after it (tracking mode: the instrument answers with its latest measurement); the truth
records the tick actually reported. The reply timing the client sees stays the modelled one
instead of every late wake-up lifting the latency.
"""

from __future__ import annotations

import contextlib
import math
import os
import random
import select
import socket
import threading
import time
import tty
from typing import Callable, List, NamedTuple, Optional, Tuple

import numpy as np

from .protocol import (
    RC,
    GeoComProtocolError,
    Rpc,
    encode_reply,
    parse_request,
)

__all__ = ["LATE_S", "SimulatorError", "FaultRates", "SimConfig", "TruthRecord", "Ms60Simulator", "builtin_track",
           "tum_track"]


LATE_S = 0.0005
"""A coordinate reply due more than this long ago (s) is measured again (an idle host's sleep
overshoots by ~0.1–0.3 ms; a loaded one by several ms)."""

_MAX_REMEASURE = 20  # then send late rather than never (a host too loaded to keep any timing)


class SimulatorError(ValueError):
    """Bad simulator settings (names the setting) or a trajectory that cannot be played."""


class FaultRates(NamedTuple):
    """Random faults. Per reply: ``garbage``, ``drop``, ``late``, ``warning``, ``spike``
    (probabilities); per second: ``lock_loss``, ``link_loss`` (rates, 1/s) with outages lasting
    uniformly ``outage_s`` seconds."""

    garbage: float = 0.0
    drop: float = 0.0
    late: float = 0.0
    warning: float = 0.0
    spike: float = 0.0
    lock_loss: float = 0.0
    link_loss: float = 0.0
    outage_s: Tuple[float, float] = (0.3, 1.5)


class SimConfig(NamedTuple):
    """Simulator settings: ``baud`` (bit/s), ``latency_s`` and ``jitter_s`` (reply delay after
    the measurement is latency ± jitter, uniform, s), ``spike_s`` (extra delay of a latency
    spike, s), ``late_s`` (delay of a late reply, s), instrument clock ``clock_offset_ms`` (ms),
    ``clock_drift`` (dimensionless, 1e-6 = 1 ppm), ``wrap_ms`` (counter modulus), ``faults``."""

    baud: int = 115200
    latency_s: float = 0.012
    jitter_s: float = 0.010
    spike_s: float = 0.150
    late_s: float = 0.8
    clock_offset_ms: float = 123456.0
    clock_drift: float = 40e-6
    wrap_ms: int = 2 ** 32
    faults: FaultRates = FaultRates()
    name: str = "MS60"
    serial_number: int = 1234567
    firmware: Tuple[int, int, int] = (7, 10, 2)

    @property
    def min_latency_s(self) -> float:
        """The shortest measurement-to-first-reply-byte time (s)."""
        return self.latency_s - self.jitter_s


class TruthRecord(NamedTuple):
    """One TMC_GetCoordinate answer: true host time of the measurement (s), instrument time
    (raw ms), true prism position (m, map), rc, transaction id, whether the reply was sent."""

    time_s: float
    instrument_ms: int
    position: Tuple[float, float, float]
    rc: int
    trid: Optional[int]
    sent: bool


class _Answer(NamedTuple):
    """A reply waiting for its time: ``data`` (bytes), ``send_s`` (host time its last byte is due,
    s), ``prefix`` (garbage sent before it), ``delay_s`` (modelled measurement-to-first-byte time,
    s) and, for TMC_GetCoordinate, its ``truth`` (None otherwise)."""

    data: bytes
    send_s: float
    prefix: bytes
    delay_s: float
    truth: Optional[TruthRecord]


def builtin_track(t: float) -> np.ndarray:
    """A smooth prism track (m): a 10 m × 6 m figure of eight around (10, 3, 1.2), period ~31 s."""
    w = 2 * math.pi / 31.4
    return np.array([10.0 + 5.0 * math.sin(w * t), 3.0 + 3.0 * math.sin(2 * w * t), 1.2 + 0.05 * math.sin(w * t)])


def tum_track(path: str) -> Callable[[float], np.ndarray]:
    """Prism positions of a TUM file as a function of time since its first stamp (looped)."""
    from ..tum import TumError, read_tum

    try:
        traj = read_tum(path)
    except TumError as e:
        raise SimulatorError(str(e)) from None
    if len(traj.stamps) < 2 or not np.all(np.diff(traj.stamps) > 0):
        raise SimulatorError(f"{path}: need ≥ 2 poses with increasing stamps")
    t_rel = traj.stamps - traj.stamps[0]
    period = float(t_rel[-1])

    def position(t: float) -> np.ndarray:
        tt = t % period
        return np.array([np.interp(tt, t_rel, traj.positions[:, k]) for k in range(3)])

    return position


class Ms60Simulator:
    """The instrument. Start it with :meth:`serve_pty` or :meth:`serve_tcp`; stop with :meth:`close`."""

    def __init__(self, config: Optional[SimConfig] = None, track: Callable[[float], np.ndarray] = builtin_track,
                 seed: Optional[int] = None):
        config = SimConfig() if config is None else config
        if config.baud <= 0 or config.latency_s < config.jitter_s or config.jitter_s < 0:
            raise SimulatorError("baud > 0 and latency_s ≥ jitter_s ≥ 0 are required")
        self.config = config
        self.track = track
        self._rng = random.Random(seed)
        self._state_lock = threading.Lock()
        self.t_boot = time.time()
        self.prism_visible = True
        self.locked = False
        self.measuring = False
        self.user_lock = False
        self.station = (0.0, 0.0, 0.0, 0.0)
        self.prism_constant_m = 0.0
        self.edm_mode = 0
        self.truth: List[TruthRecord] = []
        self.events: List[Tuple[float, str, float]] = []  # (start s, kind, end s or start)
        self.requests = 0
        self._link_down_until = 0.0
        self._stop = threading.Event()
        self._threads: List[threading.Thread] = []
        self._pty: Optional[Tuple[int, int]] = None
        self._server: Optional[socket.socket] = None
        self._conn: Optional[socket.socket] = None

    # --- instrument model ----------------------------------------------------------------
    def instrument_ms_at(self, t: float) -> float:
        """Instrument counter (ms, not wrapped, fractional) at host time ``t`` (s)."""
        c = self.config
        return (t - self.t_boot) * (1.0 + c.clock_drift) * 1000.0 + c.clock_offset_ms

    def host_time_of(self, counter_ms: float) -> float:
        """Host time (s) at which the unwrapped counter reads ``counter_ms``."""
        c = self.config
        return self.t_boot + (counter_ms - c.clock_offset_ms) / 1000.0 / (1.0 + c.clock_drift)

    def _event(self, kind: str, until: Optional[float] = None) -> None:
        now = time.time()
        self.events.append((now, kind, now if until is None else until))

    def set_prism_visible(self, visible: bool) -> None:
        """Hide (lock is lost at once) or show the prism (lock needs AUT_LockIn again)."""
        with self._state_lock:
            self.prism_visible = bool(visible)
            if not visible:
                self.locked = False
        self._event("prism_visible" if visible else "prism_hidden")

    def link_down(self, duration_s: float) -> None:
        """Break the link for ``duration_s`` seconds (TCP: close and refuse; pty: silence)."""
        self._link_down_until = time.time() + float(duration_s)
        self._event("link_down", self._link_down_until)
        conn = self._conn
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)

    @property
    def link_up(self) -> bool:
        return time.time() >= self._link_down_until

    def _coordinate(self, tick: int, rc: int, trid: Optional[int]) -> Tuple[bytes, TruthRecord]:
        """TMC_GetCoordinate reply measured at counter ``tick`` (unwrapped ms) with return code
        ``rc`` (no position unless 0 or a warning), and its truth record."""
        c = self.config
        t_meas = self.host_time_of(tick)
        t_ms = int(tick) % c.wrap_ms
        p = self.track(t_meas - self.t_boot)
        e, n, h = (float(v) for v in p) if rc != RC.TMC_ANGLE_OK else (0.0, 0.0, 0.0)
        reply = encode_reply(rc, (e, n, h, t_ms, e, n, h, t_ms), 0, trid)
        return reply, TruthRecord(t_meas, t_ms, (float(p[0]), float(p[1]), float(p[2])), int(rc), trid, True)

    def _remeasured(self, answer: _Answer, now: float) -> Optional[_Answer]:
        """None if ``answer`` may still be sent at host time ``now`` (s), else the same reply
        measured at the first counter tick from which its latency ``delay_s`` ends after ``now``."""
        truth = answer.truth
        if truth is None or now - answer.send_s <= LATE_S:
            return None
        baud = self.config.baud
        tick = math.ceil(self.instrument_ms_at(now - answer.delay_s - 10.0 * len(answer.data) / baud))
        while True:  # a shorter reply is due earlier on the wire: then the next tick
            data, later = self._coordinate(tick, truth.rc, truth.trid)
            send_s = later.time_s + answer.delay_s + 10.0 * len(data) / baud
            if send_s >= now:
                return answer._replace(data=data, truth=later, send_s=send_s)
            tick += 1

    def _handle(self, line: bytes, t_complete: float) -> Optional[_Answer]:
        """Answer one request line completed at ``t_complete`` (s), or None (no answer)."""
        try:
            req = parse_request(line)
        except GeoComProtocolError:
            return None
        self.requests += 1
        c, f, rng = self.config, self.config.faults, self._rng
        t_meas = t_complete
        values: tuple = ()
        rc = RC.OK
        reply: Optional[bytes] = None
        truth: Optional[TruthRecord] = None
        with self._state_lock:
            rpc = req.rpc
            if rpc == Rpc.TMC_GetCoordinate:
                tick = math.floor(self.instrument_ms_at(t_complete)) + 1
                rc = RC.TMC_ANGLE_OK
                if self.locked and self.measuring:
                    rc = RC.OK
                    if rng.random() < f.warning:
                        rc = rng.choice((RC.TMC_NO_FULL_CORRECTION, RC.TMC_ACCURACY_GUARANTEE))
                reply, truth = self._coordinate(tick, rc, req.trid)
                t_meas = truth.time_s
            elif rpc == Rpc.TMC_GetSimpleCoord:
                p = self.track(t_complete - self.t_boot)
                rc = RC.OK if (self.locked and self.measuring) else RC.TMC_ANGLE_OK
                values = tuple(float(v) for v in p) if rc == RC.OK else (0.0, 0.0, 0.0)
            elif rpc == Rpc.COM_NullProc:
                pass
            elif rpc == Rpc.CSV_GetInstrumentName:
                values = (c.name,)
            elif rpc == Rpc.CSV_GetInstrumentNo:
                values = (c.serial_number,)
            elif rpc in (Rpc.CSV_GetSWVersion, Rpc.COM_GetSWVersion):
                values = c.firmware
            elif rpc == Rpc.AUT_LockIn:
                if self.prism_visible:
                    self.locked = True
                else:
                    rc = RC.AUT_NO_TARGET
            elif rpc == Rpc.MOT_ReadLockStatus:
                values = (1 if self.locked else 0,)
            elif rpc == Rpc.AUS_SetUserLockState and len(req.params) == 1:
                self.user_lock = req.params[0] == "1"
            elif rpc == Rpc.TMC_SetEdmMode and len(req.params) == 1:
                self.edm_mode = int(req.params[0])
            elif rpc in (Rpc.BAP_SetPrismType, Rpc.BAP_SetMeasPrg, Rpc.TMC_SetOrientation) and len(req.params) == 1:
                pass
            elif rpc == Rpc.TMC_SetPrismCorr and len(req.params) == 1:
                self.prism_constant_m = float(req.params[0])
            elif rpc == Rpc.TMC_GetPrismCorr:
                values = (self.prism_constant_m,)
            elif rpc == Rpc.TMC_DoMeasure and len(req.params) == 2:
                self.measuring = int(req.params[0]) != 0
            elif rpc == Rpc.TMC_SetStation and len(req.params) == 4:
                self.station = tuple(float(v) for v in req.params)
            elif rpc == Rpc.TMC_GetStation:
                values = self.station
            elif rpc in Rpc._value2member_map_:
                rc = RC.IVPARAM
            else:
                rc = RC.COM_PROC_UNAVAIL
        if reply is None:
            reply = encode_reply(rc, values, 0, req.trid)
        delay = c.latency_s + rng.uniform(-c.jitter_s, c.jitter_s)
        if rng.random() < f.spike:
            delay += c.spike_s
        if rng.random() < f.late:
            delay += c.late_s
        drop = rng.random() < f.drop
        prefix = bytes(rng.randrange(32, 127) for _ in range(rng.randint(1, 40))) if rng.random() < f.garbage else b""
        if rng.random() < 0.5 and prefix:
            prefix += b"\r\n"
        if drop:
            if truth is not None:
                self.truth.append(truth._replace(sent=False))
            return None
        return _Answer(reply, t_meas + delay + 10.0 * len(reply) / c.baud, prefix, delay, truth)

    # --- transports ------------------------------------------------------------------------
    def _serve_stream(self, read: Callable[[float], bytes], write: Callable[[bytes], None]) -> None:
        """Read request lines, answer them one after the other with the wire timing."""
        buf = bytearray()
        first_byte_t: Optional[float] = None
        while not self._stop.is_set():
            chunk = read(0.05)
            if chunk is None:
                return
            if not self.link_up:
                buf.clear()
                continue
            if chunk:
                if not buf:
                    first_byte_t = time.time()
                buf += chunk
            while b"\n" in buf:
                i = buf.index(b"\n")
                line = bytes(buf[: i + 1])
                del buf[: i + 1]
                t_complete = max(time.time(), (first_byte_t or time.time()) + 10.0 * len(line) / self.config.baud)
                first_byte_t = time.time() if buf else None
                answer = self._handle(line, t_complete)
                if answer is None:
                    continue
                for _ in range(_MAX_REMEASURE):
                    wait = answer.send_s - time.time()
                    if wait > 0:
                        time.sleep(wait)
                    later = self._remeasured(answer, time.time())
                    if later is None:
                        break
                    answer = later
                truth = answer.truth
                if not self.link_up or self._stop.is_set():
                    if truth is not None:
                        self.truth.append(truth._replace(sent=False))
                    buf.clear()
                    break
                if truth is not None:
                    self.truth.append(truth)
                try:
                    write(answer.prefix + answer.data)
                except OSError:
                    return

    def serve_pty(self) -> str:
        """Start serving on a new pseudo-terminal; returns the path of its slave (the "serial
        port" a client opens)."""
        master, slave = os.openpty()
        tty.setraw(slave)
        self._pty = (master, slave)

        def read(timeout: float) -> Optional[bytes]:
            ready, _, _ = select.select([master], [], [], timeout)
            if not ready:
                return b""
            try:
                return os.read(master, 4096)
            except OSError:
                return None

        def write(data: bytes) -> None:
            os.write(master, data)

        self._start(lambda: self._serve_stream(read, write))
        self._start(self._random_faults)
        return os.ttyname(slave)

    def serve_tcp(self, port: int = 0) -> int:
        """Start serving on TCP 127.0.0.1:``port`` (0 = any free port), one client at a time;
        returns the port."""
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            server.bind(("127.0.0.1", int(port)))
        except OSError as e:
            raise SimulatorError(f"cannot listen on 127.0.0.1:{port}: {e.strerror}") from None
        server.listen(1)
        server.settimeout(0.1)
        self._server = server

        def accept_loop() -> None:
            while not self._stop.is_set():
                try:
                    conn, _ = server.accept()
                except socket.timeout:
                    continue
                except OSError:
                    return
                if not self.link_up:
                    conn.close()
                    continue
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._conn = conn
                self._event("client_connected")

                def read(timeout: float, conn=conn) -> Optional[bytes]:
                    ready, _, _ = select.select([conn], [], [], timeout)
                    if not ready:
                        return b""
                    try:
                        data = conn.recv(4096)
                    except OSError:
                        return None
                    return data if data else None

                self._serve_stream(read, conn.sendall)
                self._conn = None
                conn.close()

        self._start(accept_loop)
        self._start(self._random_faults)
        return server.getsockname()[1]

    def _start(self, target: Callable[[], None]) -> None:
        th = threading.Thread(target=target, daemon=True)
        th.start()
        self._threads.append(th)

    def _random_faults(self) -> None:
        """Lock losses and link outages at the configured rates (Poisson, checked every 50 ms)."""
        f, rng = self.config.faults, self._rng
        while not self._stop.wait(0.05):
            if f.lock_loss > 0 and self.prism_visible and rng.random() < f.lock_loss * 0.05:
                self.set_prism_visible(False)
                timer = threading.Timer(rng.uniform(*f.outage_s), self.set_prism_visible, (True,))
                timer.daemon = True
                timer.start()
            if f.link_loss > 0 and self.link_up and rng.random() < f.link_loss * 0.05:
                self.link_down(rng.uniform(*f.outage_s))

    def close(self) -> None:
        """Stop serving and release the pty/socket."""
        self._stop.set()
        if self._server is not None:
            self._server.close()
        if self._conn is not None:
            with contextlib.suppress(OSError):
                self._conn.shutdown(socket.SHUT_RDWR)
        for th in self._threads:
            th.join(timeout=2.0)
        if self._pty is not None:
            for fd in self._pty:
                with contextlib.suppress(OSError):
                    os.close(fd)
            self._pty = None
