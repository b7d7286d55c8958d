"""The simulator's transports: a pseudo-terminal (a serial line) or TCP on 127.0.0.1, one client.

In: a :class:`~.dispatch.GeoComDispatcher` (request line → scheduled reply) and its instrument.
Out: the replies on the wire at their due times, and the truth log completed with what was sent.
Contract: request lines are answered one after the other. On a pty a request of n bytes is complete
``10·n/baud`` s after its first byte and a reply takes its wire time too; over TCP there is no byte
timing. A motorised procedure runs in the serving thread (the instrument answers nothing else
meanwhile). A coordinate reply the host thread would send more than ``LATE_S`` late is measured
again. Random lock losses and link outages run in a thread of their own; during an outage a TCP
connection is closed and refused and a pty goes silent. :meth:`GeoComServer.close` stops all threads
and releases the pty or socket.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import threading
import time
import tty
from typing import Callable, List, Optional, Tuple

from .dispatch import Answer, GeoComDispatcher, Motion
from .instrument import SimulatorError

__all__ = ["GeoComServer"]

_MAX_REMEASURE = 20  # then send late rather than never (a host too loaded to keep any timing)
_DONE, _CUT, _GONE = "done", "cut", "gone"   # what became of a request line (_answer_line)


class GeoComServer:
    """Serves ``dispatcher`` on a pty (:meth:`serve_pty`) or TCP (:meth:`serve_tcp`); :meth:`link_down`
    injects an outage; :meth:`close` stops."""

    def __init__(self, dispatcher: GeoComDispatcher):
        self.dispatcher = dispatcher
        self.instrument = dispatcher.instrument
        self._link_down_until = 0.0
        self._stop = threading.Event()
        self._threads: List[threading.Thread] = []
        self._pty: Optional[Tuple[int, int]] = None
        self._server: Optional[socket.socket] = None
        self._conn: Optional[socket.socket] = None

    def link_down(self, duration_s: float) -> None:
        """Break the link for ``duration_s`` seconds (TCP: close and refuse; pty: silence)."""
        self._link_down_until = time.time() + float(duration_s)
        self.instrument.event("link_down", self._link_down_until)
        conn = self._conn
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)

    @property
    def link_up(self) -> bool:
        return time.time() >= self._link_down_until

    def _aborted_after(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` (s) for a stop; True when stopped or the link is down."""
        return self._stop.wait(timeout_s) or not self.link_up

    def _serve_stream(self, read: Callable[[float], bytes], write: Callable[[bytes], None]) -> None:
        """Read request lines, answer them one after the other with the wire timing."""
        d = self.dispatcher
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
                t_complete = max(time.time(), (first_byte_t or time.time()) + d.wire_s(len(line)))
                first_byte_t = time.time() if buf else None
                outcome = self._answer_line(line, t_complete, write)
                if outcome == _GONE:
                    return
                if outcome == _CUT:
                    buf.clear()
                    break

    def _answer_line(self, line: bytes, t_complete: float, write: Callable[[bytes], None]) -> str:
        """Answer the request ``line`` complete at host time ``t_complete`` (s) and write the reply when it
        is due: _DONE (sent, or no reply), _CUT (the link went down or the server stopped meanwhile: not
        sent) or _GONE (the write failed: the client is gone)."""
        d, ins = self.dispatcher, self.instrument
        answer = d.handle(line, t_complete)
        if isinstance(answer, Motion):
            answer = d.motion_answer(answer, self._aborted_after)
        if answer is None:
            return _DONE
        answer = self._when_due(answer)
        truth = answer.truth
        if not self.link_up or self._stop.is_set():
            if truth is not None:
                ins.truth.append(truth._replace(sent=False))
            return _CUT
        if truth is not None:
            ins.truth.append(truth)
        try:
            write(answer.prefix + answer.data)
        except OSError:
            return _GONE
        return _DONE

    def _when_due(self, answer: Answer) -> Answer:
        """Sleep until ``answer`` is due; a coordinate that would go out late is measured again (at most
        _MAX_REMEASURE times, then it goes out late)."""
        for _ in range(_MAX_REMEASURE):
            wait = answer.send_s - time.time()
            if wait > 0:
                time.sleep(wait)
            later = self.dispatcher.remeasured(answer, time.time())
            if later is None:
                break
            answer = later
        return answer

    def serve_pty(self) -> str:
        """Start serving on a new pseudo-terminal; returns the path of its slave (the "serial
        port" a client opens)."""
        master, slave = os.openpty()
        tty.setraw(slave)
        self._pty = (master, slave)
        self.dispatcher.byte_timing = True

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
        """Start serving on TCP 127.0.0.1:``port`` (0 = any free port), one client at a time,
        without serial byte timing (an instrument on WLAN/Ethernet); returns the port."""
        self.dispatcher.byte_timing = False
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            server.bind(("127.0.0.1", int(port)))
        except OSError as e:
            raise SimulatorError(f"cannot listen on 127.0.0.1:{port}: {e.strerror}") from None
        server.listen(1)
        server.settimeout(0.1)
        self._server = server
        self._start(lambda: self._accept_loop(server))
        self._start(self._random_faults)
        return server.getsockname()[1]

    def _accept_loop(self, server: socket.socket) -> None:
        """Accept one client after the other on ``server`` and serve it until it or the link goes."""
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
            self.instrument.event("client_connected")

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

    def _start(self, target: Callable[[], None]) -> None:
        th = threading.Thread(target=target, daemon=True)
        th.start()
        self._threads.append(th)

    def _random_faults(self) -> None:
        """Lock losses and link outages at the configured rates (Poisson, checked every 50 ms)."""
        ins = self.instrument
        f, rng = ins.config.faults, ins.rng
        while not self._stop.wait(0.05):
            if f.lock_loss > 0 and ins.prism_visible and rng.random() < f.lock_loss * 0.05:
                ins.set_prism_visible(False)
                timer = threading.Timer(rng.uniform(*f.outage_s), ins.set_prism_visible, (True,))
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
