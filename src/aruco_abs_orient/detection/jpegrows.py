"""Frames decoded in part: only the image rows that tracking reads (``process``).

In: JPEG bytes and a span of rows [r0, r1). Out: :func:`decode_jpeg_rows`, a :class:`RowFrame` (a grey uint8
array whose rows outside the span are not decoded but zero; ``rows`` says which are, :meth:`RowFrame.complete`
decodes the rest when asked) or, when the span is the whole frame or the row decoder is unavailable, a whole
grey frame; :func:`need_rows`, called by every reader of equirect pixels in :mod:`.detector` and :mod:`.sphere`,
raises :class:`RowsMissing` when a read reaches outside a RowFrame's span (the caller completes the frame and
reads again: a partial frame never gives other observations than the whole one).

Rows above the span cost only their entropy decoding, rows below it nothing (libjpeg-turbo's
``jpeg_skip_scanlines``; the IDCT is libjpeg's fast integer one, as :func:`.images.decode_jpeg`'s). The decoder is
``jpegrows.c``, compiled on first use with the system's C compiler (``$CC`` or ``cc``) against libjpeg into the
user's cache (``$XDG_CACHE_HOME`` or ``~/.cache``, ``aruco_abs_orient/``); :func:`row_decoder` says why when it
cannot be (no compiler, no ``jpeglib.h``, a libjpeg without ``jpeg_skip_scanlines``). Python 3.8, numpy, ctypes.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import subprocess
import tempfile
import threading
from typing import Optional, Tuple, Union

import numpy as np

from .images import decode_jpeg
from .params import DetectionError

__all__ = ["RowsMissing", "RowFrame", "partial", "bilinear_rows", "need_rows", "row_decoder", "decode_jpeg_rows"]

_SOURCE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "jpegrows.c")
_MSG = 200


class RowsMissing(Exception):
    """A read of a :class:`RowFrame` outside its decoded rows (caught by the tracker, which completes it)."""


class RowFrame(np.ndarray):
    """A grey frame whose rows ``rows`` = (r0, r1) are decoded and the others zero. A slice or a copy of it is a
    plain array again (its rows are not the frame's). ``completed`` is True once :meth:`complete` has run."""

    rows: Optional[Tuple[int, int]] = None
    completed = False
    _jpeg: bytes = b""

    def __array_finalize__(self, obj) -> None:
        self.rows, self._jpeg = None, b""

    def complete(self) -> np.ndarray:
        """The whole frame (decoded now, by the same decoder, so that its decoded rows are these)."""
        self.completed = True
        return _decode(row_decoder()[0], self._jpeg, self.shape, 0, self.shape[0], "jpeg")


def partial(grey: np.ndarray) -> bool:
    """Whether ``grey`` is a :class:`RowFrame` with rows not decoded (a reader then says which it reads)."""
    return getattr(grey, "rows", None) is not None


def bilinear_rows(v) -> Tuple[int, int]:
    """The rows [r0, r1) a bilinear read at row coordinates ``v`` (an array, not empty) touches: each point's row
    and the next."""
    return int(np.floor(np.min(v))), int(np.floor(np.max(v))) + 2


def need_rows(grey: np.ndarray, r0: int, r1: int) -> None:
    """Raise :class:`RowsMissing` when ``grey`` is a :class:`RowFrame` whose decoded rows do not hold [r0, r1)
    (clipped to the frame); nothing for a whole frame."""
    rows = getattr(grey, "rows", None)
    if rows is not None and (max(int(r0), 0) < rows[0] or min(int(r1), grey.shape[0]) > rows[1]):
        raise RowsMissing(f"rows {r0}..{r1} read, {rows[0]}..{rows[1]} decoded")


_LOCK = threading.Lock()
_BUILT: dict = {}


def row_decoder() -> Tuple[Optional[ctypes.CDLL], str]:
    """(the compiled decoder, "") or (None, why it is not available); built once per process and machine."""
    with _LOCK:
        if "lib" not in _BUILT:
            _BUILT["lib"], _BUILT["why"] = _build()
        return _BUILT["lib"], _BUILT["why"]


def _build() -> Tuple[Optional[ctypes.CDLL], str]:
    with open(_SOURCE, "rb") as f:
        digest = hashlib.sha256(f.read() + platform.machine().encode()).hexdigest()[:16]
    cache = os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "aruco_abs_orient")
    path = os.path.join(cache, f"jpegrows-{digest}.so")
    if not os.path.exists(path):
        try:
            os.makedirs(cache, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=".jpegrows-", suffix=".so", dir=cache)
            os.close(fd)
            cc = os.environ.get("CC") or "cc"
            done = subprocess.run([cc, "-O2", "-shared", "-fPIC", "-o", tmp, _SOURCE, "-ljpeg"], capture_output=True,
                                  timeout=120)
            if done.returncode != 0:
                os.unlink(tmp)
                lines = done.stderr.decode(errors="replace").strip().splitlines()
                return None, f"{cc} could not build the row decoder: {lines[-1] if lines else done.returncode}"
            os.replace(tmp, path)  # atomic: another process building it at the same time finds one whole file
        except (OSError, subprocess.SubprocessError) as e:
            return None, f"the row decoder could not be built in {cache}: {e}"
    try:
        lib = ctypes.CDLL(path)
    except OSError as e:
        return None, f"the row decoder {path} could not be loaded: {e}"
    lib.aao_jpeg_rows.argtypes = [ctypes.c_char_p, ctypes.c_ulong, ctypes.c_void_p, ctypes.c_int, ctypes.c_int,
                                  ctypes.c_int, ctypes.c_int, ctypes.c_char_p, ctypes.c_int,
                                  ctypes.POINTER(ctypes.c_int), ctypes.POINTER(ctypes.c_int)]
    return lib, ""


class _Unreadable(DetectionError):
    """A JPEG libjpeg could not read here (broken, or CMYK): :func:`decode_jpeg_rows` asks the whole decoder."""


def _decode(lib: ctypes.CDLL, data: bytes, shape: Tuple[int, int], r0: int, r1: int, what: str) -> np.ndarray:
    """Rows [r0, r1) of the frame (rows clipped to its height) into zeros of its shape, which ``shape`` (H, W)
    guesses (the last frame's): a wrong guess costs one more header read."""
    msg, w, h = ctypes.create_string_buffer(_MSG), ctypes.c_int(), ctypes.c_int()
    for _ in range(2):
        out = np.zeros(shape, np.uint8)
        status = lib.aao_jpeg_rows(data, len(data), out.ctypes.data, shape[1], shape[0], r0, min(r1, shape[0]), msg,
                                   _MSG, ctypes.byref(w), ctypes.byref(h))
        if status != 2 or (h.value, w.value) == shape or w.value <= 0 or h.value <= 0:
            break
        shape = _SHAPE[0] = (h.value, w.value)
    if status != 0:
        error = _Unreadable if status == 1 else DetectionError
        raise error(f"{what}: corrupt JPEG: {msg.value.decode(errors='replace')}")
    return out


_SHAPE = [(1920, 3840)]  # the last frame's (H, W): the next one's guess


def decode_jpeg_rows(data: Union[bytes, bytearray], rows: Optional[Tuple[int, int]],
                     what: str = "jpeg") -> np.ndarray:
    """The grey frame of JPEG bytes with only ``rows`` = (r0, r1) decoded (a :class:`RowFrame`), or whole (None,
    or a span holding every row: a plain array). By the row decoder when it is available, else (and for a JPEG
    it cannot read, which :func:`.images.decode_jpeg` then names or decodes) whole by decode_jpeg. Raises
    DetectionError for a corrupt or truncated JPEG (also one whose damage lies in rows it would not decode: its
    end-of-image marker is checked)."""
    buf = bytes(data)
    lib, _ = row_decoder()
    if lib is None:
        return decode_jpeg(buf, what=what)
    if len(buf) < 4 or buf[:2] != b"\xff\xd8" or buf[-2:] != b"\xff\xd9":
        raise DetectionError(f"{what}: not a whole JPEG (no start or end marker, {len(buf)} bytes)")
    r0, r1 = (0, 1 << 30) if rows is None else (max(0, int(rows[0])), int(rows[1]))
    if r1 <= r0:  # nothing asked: the whole frame
        r0, r1 = 0, 1 << 30
    try:
        grey = _decode(lib, buf, tuple(_SHAPE[0]), r0, r1, what)
    except _Unreadable:  # broken, or what libjpeg cannot turn grey itself (CMYK): the whole decoder says which
        return decode_jpeg(buf, what=what)
    height = grey.shape[0]
    if r0 == 0 and r1 >= height:
        return grey
    if r0 >= height:  # none of the frame's rows asked: the whole frame
        return _decode(lib, buf, grey.shape, 0, height, what)
    frame = grey.view(RowFrame)
    frame.rows, frame._jpeg = (r0, min(r1, height)), buf
    return frame
