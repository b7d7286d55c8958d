"""Frames in: validation of equirect images and JPEG decoding.

In: a numpy image (grey, BGR or BGRA uint8) or JPEG bytes. Out: a grey uint8 equirect image
(2:1) for the detector (:func:`to_grey`, :func:`decode_jpeg`, optionally reduced by 2, 4 or 8
in the DCT; :func:`frame_to_grey` takes either); :class:`~.params.DetectionError` naming the
frame otherwise. Decoding holds no state and releases the GIL: it may run in its own thread.
"""

from __future__ import annotations

import cv2
import numpy as np

from .params import DetectionError

__all__ = ["to_grey", "decode_jpeg", "frame_to_grey"]


def to_grey(image, what: str = "image") -> np.ndarray:
    """Validate an equirect frame (grey H×W, or BGR/BGRA H×W×3/4, uint8, W = 2H) and return grey.

    Raises DetectionError naming ``what``.
    """
    if not isinstance(image, np.ndarray):
        raise DetectionError(f"{what}: expected a numpy image, got {type(image).__name__}")
    if image.size == 0:
        raise DetectionError(f"{what}: empty image {image.shape}")
    if image.dtype != np.uint8:
        raise DetectionError(f"{what}: expected uint8 pixels, got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    elif image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    elif image.ndim != 2:
        raise DetectionError(f"{what}: expected grey H×W or colour H×W×3, got shape {image.shape}")
    h, w = image.shape
    if w != 2 * h:
        raise DetectionError(f"{what}: an equirectangular frame is 2:1, got {w}×{h}")
    return image


def frame_to_grey(image, reduce: int = 1, what: str = "image") -> np.ndarray:
    """The grey frame of JPEG bytes (:func:`decode_jpeg`, reduced by ``reduce`` in the DCT) or of a numpy
    image (:func:`to_grey`: a mono8 array is used as it is, without a copy). Raises DetectionError."""
    if isinstance(image, (bytes, bytearray, memoryview)):
        return decode_jpeg(bytes(image), reduce=reduce, what=what)
    return to_grey(image, what)


def decode_jpeg(data, reduce: int = 1, what: str = "jpeg") -> np.ndarray:
    """Decode JPEG bytes to a grey uint8 image, optionally reduced by 2, 4 or 8 in the DCT.

    Uses simplejpeg (libjpeg-turbo, the fastest measured here: bench/detection.py) when
    installed, with libjpeg's fast integer IDCT: 13 % less CPU in ``process`` on the realistic
    demo, its heading RMSE unchanged (0.012°), its pixels within a few grey levels of the exact
    IDCT's. Else ``cv2.imdecode`` (IMREAD_GRAYSCALE / IMREAD_REDUCED_GRAYSCALE_n, exact IDCT).
    Raises DetectionError on a corrupt or truncated JPEG.
    """
    if reduce not in (1, 2, 4, 8):
        raise DetectionError(f"{what}: reduce must be 1, 2, 4 or 8, got {reduce!r}")
    buf = bytes(data) if not isinstance(data, (bytes, bytearray)) else data
    if len(buf) < 4 or buf[:2] != b"\xff\xd8":
        raise DetectionError(f"{what}: not a JPEG (no SOI marker, {len(buf)} bytes)")
    try:
        import simplejpeg
    except ImportError:  # Noetic robots: OpenCV only
        simplejpeg = None
    if simplejpeg is not None:
        try:
            h, w = simplejpeg.decode_jpeg_header(buf)[:2]
            img = simplejpeg.decode_jpeg(buf, colorspace="GRAY", min_height=h // reduce, min_width=w // reduce,
                                         min_factor=float(reduce), fastdct=True)
        except ValueError as e:
            raise DetectionError(f"{what}: corrupt JPEG: {e}") from None
        return img[:, :, 0] if img.ndim == 3 else img
    flag = {1: cv2.IMREAD_GRAYSCALE, 2: cv2.IMREAD_REDUCED_GRAYSCALE_2, 4: cv2.IMREAD_REDUCED_GRAYSCALE_4,
            8: cv2.IMREAD_REDUCED_GRAYSCALE_8}[reduce]
    img = cv2.imdecode(np.frombuffer(buf, dtype=np.uint8), flag)
    if img is None or buf[-2:] != b"\xff\xd9":
        raise DetectionError(f"{what}: corrupt or truncated JPEG ({len(buf)} bytes)")
    if reduce > 1 and not _IMDECODE_REDUCES:  # average reduce×reduce blocks, as the DCT scaling does
        img = cv2.resize(img, (-(-img.shape[1] // reduce), -(-img.shape[0] // reduce)), interpolation=cv2.INTER_AREA)
    return img


def _imdecode_reduces() -> bool:
    """Whether ``cv2.imdecode`` honours IMREAD_REDUCED_* (OpenCV 4.6 and 4.11 do; Noetic's 4.2
    ignores it and decodes at full size)."""
    probe = cv2.imencode(".jpg", np.zeros((16, 16), np.uint8))[1]
    return cv2.imdecode(probe, cv2.IMREAD_REDUCED_GRAYSCALE_2).shape == (8, 8)


_IMDECODE_REDUCES = _imdecode_reduces()
