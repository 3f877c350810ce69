"""PNG and EXR files, the one place facegeo encodes and decodes them (the map PNGs of an asset
folder and of the USD/glTF writers, overlays, previews, skin masks, unwrap's EXR maps, training
data). Arrays are in RGB(A) channel order here; OpenCV's BGR order stays inside this module.

Photos are read by :mod:`facegeo.photo` (EXIF orientation, alpha, size checks), not here.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

# OpenCV reads this when it first encodes or decodes an EXR (checked lazily in OpenCV 4.x, so it
# also works when cv2 was imported earlier); set before cv2 is imported to be safe.
os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")

import numpy as np  # noqa: E402

from facegeo.errors import InputError  # noqa: E402
from facegeo.native_stderr import silenced_native_stderr  # noqa: E402

__all__ = ["png_bytes", "read_png", "read_png_file", "plain_png", "exr_bytes", "to_uint"]

#: The chunks of a PNG file that :func:`plain_png` accepts: the image itself and notes that do not
#: change how it is shown (text, time, physical size); a colour space, gamma, significant bits,
#: transparency or animation chunk makes a file not plain.
_PLAIN_CHUNKS = frozenset({b"IHDR", b"PLTE", b"IDAT", b"IEND", b"tEXt", b"zTXt", b"iTXt", b"tIME", b"pHYs"})
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _bgr(image: np.ndarray) -> np.ndarray:
    """RGB(A) <-> BGR(A) (the same swap both ways); grey images unchanged."""
    img = np.ascontiguousarray(image)
    if img.ndim == 3 and img.shape[2] == 3:
        return np.ascontiguousarray(img[:, :, ::-1])
    if img.ndim == 3 and img.shape[2] == 4:
        return np.ascontiguousarray(img[:, :, [2, 1, 0, 3]])
    return img


def to_uint(array: np.ndarray, bits: int) -> np.ndarray:
    """Values in [0, 1] (clipped) to uint8 (``bits`` 8) or uint16 (16), rounded to nearest."""
    q = np.array(array, dtype=np.float64)  # a copy, worked on in place
    np.clip(q, 0.0, 1.0, out=q)
    q *= (1 << bits) - 1
    return np.round(q, out=q).astype(np.uint8 if bits == 8 else np.uint16)


def png_bytes(image: np.ndarray) -> bytes:
    """PNG bytes of an (H, W), (H, W, 3) or (H, W, 4) uint8/uint16 image (RGB(A) order).

    zlib's run-length strategy with the "up" row filter, chosen by measurement
    (``benchmarks/bench_png.py``; RESULTS.md, "Issue 29: export"): on the 1K maps of a
    reconstruct it takes a third of the time of zlib level 1 with the default strategy and
    libpng's adaptive filters, for files 4 % smaller; levels 6 to 9 would save 3-4 % more bytes
    for 5 to 15 times that time. (The strategy is set after the level, which resets it.)
    """
    import cv2

    params = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE,
              cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP]
    ok, buf = cv2.imencode(".png", _bgr(image), params)
    if not ok:  # pragma: no cover
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def read_png(path: str | os.PathLike[str]) -> np.ndarray:
    """An 8- or 16-bit PNG as stored: (H, W) or (H, W, C) uint8/uint16, RGB(A) order.

    Raises:
        InputError: the file is missing or not a readable image.
    """
    return read_png_file(path)[0]


def read_png_file(path: str | os.PathLike[str]) -> tuple[np.ndarray, bytes]:
    """:func:`read_png` and the file's bytes: ``(image as stored, RGB(A) order; the PNG file)``,
    for a writer that may embed the file as it is (:func:`plain_png`).

    Raises:
        InputError: the file is missing or not a readable image.
    """
    import cv2

    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise InputError(path, "image", "a readable PNG file", exc.strerror or str(exc)) from None
    with silenced_native_stderr():  # libpng prints "libpng error: ..." itself; the InputError says it
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(path, "image", "a readable PNG file")
    return _bgr(img), data


def plain_png(data: bytes) -> bool:
    """Whether ``data`` is a PNG file that holds its pixels and nothing that changes how they are
    shown (only the chunks of :data:`_PLAIN_CHUNKS`), so that any other PNG file of the same
    pixels may stand in for it (and it for them)."""
    if not data.startswith(_PNG_SIGNATURE):
        return False
    pos = len(_PNG_SIGNATURE)
    while pos + 8 <= len(data):
        length, kind = struct.unpack_from(">I4s", data, pos)
        if kind not in _PLAIN_CHUNKS:
            return False
        if kind == b"IEND":
            return True
        pos += 12 + length  # length, type, data, CRC
    return False


def exr_bytes(image: np.ndarray) -> bytes:
    """A float32 OpenEXR file (ZIP compression) of an (H, W), (H, W, 3) RGB or (H, W, 4) RGBA
    array, channels in RGB(A) order."""
    import cv2

    params = [cv2.IMWRITE_EXR_TYPE, cv2.IMWRITE_EXR_TYPE_FLOAT]
    if hasattr(cv2, "IMWRITE_EXR_COMPRESSION_ZIP"):
        params += [cv2.IMWRITE_EXR_COMPRESSION, cv2.IMWRITE_EXR_COMPRESSION_ZIP]
    ok, buf = cv2.imencode(".exr", _bgr(np.asarray(image, dtype=np.float32)), params)
    if not ok:  # pragma: no cover - OpenCV built without OpenEXR
        raise RuntimeError("OpenCV could not encode EXR (is OPENCV_IO_ENABLE_OPENEXR=1 set?)")
    return buf.tobytes()
