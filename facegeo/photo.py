"""Reading a face photo robustly: any common file in, one (H, W, 3) uint8 RGB array out.

Every photo goes through :func:`load_photo`, which turns the many ways an image file can be odd
(EXIF rotation, 16-bit samples, greyscale, CMYK, transparency, several frames, a huge or a tiny
size, a truncated or non-image file) into either a plain array or an :class:`InputError` that
names the file. In-memory arrays go through :func:`as_rgb_uint8`.

Colour: pixels are returned as stored, 8 bits per channel, and treated as sRGB. No colour
management is done; an embedded ICC profile that is not sRGB is reported in ``Photo.notes``.
"""

from __future__ import annotations

import functools
import importlib
import os
import stat
import threading
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, ImageFile

from facegeo.errors import InputError
from facegeo.native_stderr import silenced_native_stderr

__all__ = ["Photo", "load_photo", "as_rgb_uint8", "MIN_SIDE", "DEFAULT_MAX_SIDE"]

#: Smallest accepted short side in pixels: no face can be found below that.
MIN_SIDE = 32
#: Default longest side after loading; larger photos are downscaled (cv2.INTER_AREA).
DEFAULT_MAX_SIDE = 2048

#: Pillow plugins a photo may be decoded with (MPO, the multi-picture JPEG of many phones, is
#: opened by the JPEG plugin). Restricting the list keeps Pillow from guessing exotic formats
#: (and from ever running Ghostscript for EPS).
_FORMATS = ("PNG", "JPEG", "TIFF", "BMP", "DIB", "GIF", "WEBP", "PPM", "AVIF")
#: The Pillow plugins that register :data:`_FORMATS` (``Image.init()`` imports all ~45, 20-40 ms).
_PLUGINS = ("PngImagePlugin", "JpegImagePlugin", "TiffImagePlugin", "BmpImagePlugin", "GifImagePlugin", "WebPImagePlugin",
            "PpmImagePlugin", "AvifImagePlugin")
#: The plugin of a file whose first bytes say its format for certain (PNG and JPEG, most photos):
#: only that one is imported (the other plugins' imports, subprocess's among them, cost ~10 ms).
_SIGNATURE_PLUGINS = ((b"\x89PNG\r\n\x1a\n", "PngImagePlugin"), (b"\xff\xd8\xff", "JpegImagePlugin"))
_EXPECTED_IMAGE = "a readable PNG/JPEG/... image (PNG, JPEG, TIFF, BMP, GIF, WebP, PPM)"

_ORIENTATION_NAMES = {
    2: "mirrored left-right",
    3: "rotated 180°",
    4: "mirrored top-bottom",
    5: "transposed",
    6: "rotated 90° clockwise",
    7: "transversed",
    8: "rotated 90° counter-clockwise",
}

# ImageFile.LOAD_TRUNCATED_IMAGES is a Pillow-wide switch; it is forced off while a photo is
# decoded (so a truncated file is an error, never a grey-filled image) and restored afterwards.
_PIL_LOCK = threading.Lock()


@dataclass(frozen=True, eq=False)
class Photo:
    """A decoded photo, ready for face detection.

    Attributes:
        image: (H, W, 3) uint8, C-contiguous, RGB (sRGB values as stored in the file), EXIF
            orientation applied, downscaled so that max(H, W) <= ``max_side``.
        path: the file it was read from, as given.
        scale: the factor applied to the (EXIF-rotated) original pixel grid: 1.0 when untouched,
            < 1 when downscaled. A pixel coordinate x in ``image`` is x / scale in the original
            (up to the < 0.5 px rounding of the output size).
        original_size: (W, H) of the original image after EXIF rotation, before downscaling.
        notes: human-readable remarks about what was done to the pixels, e.g.
            ``"downscaled from 8000x6000 to 2048x1536"`` or ``"alpha channel composited over
            white"``; empty for a plain 8-bit RGB file of acceptable size.
        opacity: None for an opaque photo; else (H, W) float32 alpha in [0, 1] on ``image``'s
            grid (the fit refuses a face that is mostly transparent: facegeo.fitting.checks).

    Equality is identity (``eq=False``): comparing arrays element-wise is left to the caller.
    """

    image: np.ndarray
    path: str
    scale: float
    original_size: tuple[int, int]
    notes: tuple[str, ...] = ()
    opacity: np.ndarray | None = None

    def __post_init__(self) -> None:
        img = self.image
        if not (isinstance(img, np.ndarray) and img.ndim == 3 and img.shape[2] == 3
                and img.dtype == np.uint8 and img.flags.c_contiguous):
            raise ValueError("Photo.image must be a C-contiguous (H, W, 3) uint8 array")
        if self.opacity is not None and np.shape(self.opacity) != img.shape[:2]:
            raise ValueError(f"Photo.opacity must be None or an (H, W) = {img.shape[:2]} array, got {np.shape(self.opacity)}")
        object.__setattr__(self, "notes", tuple(self.notes))
        object.__setattr__(self, "original_size", tuple(int(v) for v in self.original_size))

    @property
    def size(self) -> tuple[int, int]:
        """(W, H) of ``image``."""
        return int(self.image.shape[1]), int(self.image.shape[0])


# --------------------------------------------------------------------------------------------
# In-memory arrays
# --------------------------------------------------------------------------------------------


def as_rgb_uint8(array: np.ndarray, source: str = "<array>") -> np.ndarray:
    """Validate an in-memory image and return it as a new (H, W, 3) uint8 RGB array.

    Accepted shapes: (H, W) or (H, W, 1) greyscale, (H, W, 3) RGB, (H, W, 4) RGBA (channel order
    R, G, B[, A]; convert OpenCV's BGR first), with H, W >= 1. Accepted dtypes:

    * uint8: used as is;
    * uint16: reduced to 8 bit as round(v / 257) (65535 -> 255, not clipped);
    * float16/32/64: values must be finite and in [0, 1] (overshoots up to 1e-6 are clipped);
      quantised as floor(v * 255 + 0.5).

    Greyscale is repeated into three channels; alpha is composited over white
    (out = c·a + white·(1 − a), straight, not premultiplied alpha). The result is always a new
    C-contiguous array that shares no memory with ``array``.

    Raises:
        InputError: (``source``, "image array", ...) for any other shape, dtype, NaN/inf or
            out-of-range floats.
    """
    rgb, _notes = _to_rgb_uint8(array, source, allow_grey_alpha=False)
    return rgb


def _to_rgb_uint8(array: object, source: str, *, allow_grey_alpha: bool) -> tuple[np.ndarray, list[str]]:
    """:func:`as_rgb_uint8` plus the notes describing what was converted.

    With ``allow_grey_alpha`` a (H, W, 2) grey+alpha array (Pillow's "LA") is accepted too.
    """
    if not isinstance(array, np.ndarray):
        raise InputError(source, "image array", "a numpy array", type(array).__name__)
    notes: list[str] = []
    arr = array
    shapes = "(H, W), (H, W, 1), (H, W, 3) or (H, W, 4)"
    channels_ok = (1, 2, 3, 4) if allow_grey_alpha else (1, 3, 4)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    elif arr.ndim != 3 or arr.shape[2] not in channels_ok:
        raise InputError(source, "image array shape", shapes, str(tuple(array.shape)))
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise InputError(source, "image array shape", f"{shapes} with H, W >= 1",
                         str(tuple(array.shape)))

    kind = arr.dtype.kind
    if arr.dtype == np.uint8:
        maxval = 255
    elif arr.dtype == np.uint16:
        maxval = 65535
    elif kind == "f":
        if arr.dtype.itemsize < 4:
            arr = arr.astype(np.float32)
        finite = np.isfinite(arr)
        if not finite.all():
            bad = arr[~finite]
            what = "NaN" if np.isnan(bad).any() else "infinite values"
            raise InputError(source, "image array values", "finite values in [0, 1]", what)
        lo, hi = float(arr.min()), float(arr.max())
        if lo < -1e-6 or hi > 1.0 + 1e-6:
            raise InputError(source, "image array values", "float values in [0, 1]",
                             f"values in [{lo:g}, {hi:g}]")
        arr = np.clip(arr, 0.0, 1.0)
        maxval = 0  # marks floats
    else:
        raise InputError(source, "image array dtype", "uint8, uint16 or float in [0, 1]",
                         str(arr.dtype))

    n = arr.shape[2]
    colour = arr[:, :, :1] if n in (1, 2) else arr[:, :, :3]
    alpha = arr[:, :, n - 1] if n in (2, 4) else None

    if alpha is not None:
        opaque = bool((alpha >= (maxval or 1.0)).all())
        if opaque:
            notes.append("alpha channel (fully opaque) dropped")
        else:
            notes.append("alpha channel composited over white")
            colour = _composite_over_white(colour, alpha, maxval)

    if maxval == 255:
        out8 = colour.astype(np.uint8, copy=False)
    elif maxval == 65535:
        # round(v / 257) in integers: 257 is odd, so ties cannot occur.
        out8 = ((colour.astype(np.uint32) + 128) // 257).astype(np.uint8)
        notes.append("16-bit image reduced to 8 bit")
    else:
        out8 = np.floor(colour * 255.0 + 0.5).astype(np.uint8)
        notes.append("floating-point image quantised to 8 bit")

    if out8.shape[2] == 1:
        rgb = np.repeat(out8, 3, axis=2)
        notes.append("greyscale expanded to RGB")
    else:
        rgb = np.array(out8, dtype=np.uint8, order="C", copy=True)
    if np.shares_memory(rgb, array):  # pragma: no cover - np.repeat/np.array always copy
        rgb = rgb.copy()
    return rgb, notes


def _composite_over_white(colour: np.ndarray, alpha: np.ndarray, maxval: int) -> np.ndarray:
    """c·a + M·(M − a) over M (straight alpha), rounded, in the input's integer range or float."""
    a = alpha[:, :, None]
    if maxval == 0:
        return colour * a + (1.0 - a)
    # uint8: worst case 255·255 + 127 fits uint16; uint16 needs 64 bits to be safe.
    work = np.uint16 if maxval == 255 else np.uint64
    c = colour.astype(work)
    a = a.astype(work)
    m = work(maxval)
    return (c * a + m * (m - a) + m // 2) // m


# --------------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------------


def load_photo(path: str | os.PathLike[str], max_side: int = DEFAULT_MAX_SIDE) -> Photo:
    """Read a photo file into a :class:`Photo` ((H, W, 3) uint8 RGB, EXIF orientation applied).

    What is handled (each remark goes into ``Photo.notes``):

    * formats PNG, JPEG (incl. phone MPO), TIFF, BMP, GIF, WebP, PPM (and AVIF where Pillow has
      it); the format is sniffed from the content, not the file name;
    * EXIF orientation 2..8 (same result as ``PIL.ImageOps.exif_transpose``);
    * 16-bit samples (greyscale or colour, PNG/TIFF) reduced to 8 bit as round(v / 257);
    * greyscale (1-bit, L, LA, I;16) and palette images expanded to RGB, CMYK converted to RGB
      (Pillow's conversion, no ICC);
    * transparency (RGBA, LA, palette with a transparent index) composited over white;
    * multi-frame files (GIF, TIFF, MPO): the first frame;
    * images whose longer side exceeds ``max_side``: downscaled with cv2.INTER_AREA so that the
      longer side is ``max_side``; ``Photo.scale`` records the factor.

    Raises:
        InputError: the file is missing, a directory, empty, not an image, truncated or corrupt,
            a decompression bomb (Pillow's ``MAX_IMAGE_PIXELS`` check), in an unsupported pixel
            format, or smaller than :data:`MIN_SIDE` px on its short side (before or after
            downscaling).
        ValueError: ``max_side`` < :data:`MIN_SIDE` (a programming error, not bad input).
    """
    if int(max_side) != max_side or max_side < MIN_SIDE:
        raise ValueError(f"max_side must be an integer >= {MIN_SIDE}, got {max_side!r}")
    max_side = int(max_side)
    source = os.fspath(path)
    p = Path(source)
    _check_file(p, source)

    notes: list[str] = []
    array, mode_notes, orientation, frames, icc_note = _decode(p, source)
    if frames > 1:
        notes.append(f"first of {frames} frames used")
    notes.extend(mode_notes)

    rgb, conv_notes = _to_rgb_uint8(array, source, allow_grey_alpha=True)
    notes.extend(n for n in conv_notes if n not in notes)
    opacity = _opacity(array)
    if icc_note:
        notes.append(icc_note)

    if orientation in _ORIENTATION_NAMES:
        rgb = _apply_orientation(rgb, orientation)
        opacity = None if opacity is None else np.ascontiguousarray(_apply_orientation(opacity[:, :, None], orientation)[:, :, 0])
        notes.append(f"EXIF orientation {orientation} applied ({_ORIENTATION_NAMES[orientation]})")
    rgb = np.ascontiguousarray(rgb)
    h, w = rgb.shape[:2]

    scale = 1.0
    if max(w, h) > max_side:
        scale = max_side / max(w, h)
        new_w = max(1, min(max_side, int(round(w * scale))))
        new_h = max(1, min(max_side, int(round(h * scale))))
        rgb = cv2.resize(rgb, (new_w, new_h), interpolation=cv2.INTER_AREA)
        rgb = np.ascontiguousarray(rgb)
        if opacity is not None:
            opacity = cv2.resize(opacity, (new_w, new_h), interpolation=cv2.INTER_AREA)
        notes.append(f"downscaled from {w}x{h} to {new_w}x{new_h}")
        if min(new_w, new_h) < MIN_SIDE:
            raise InputError(source, "image size",
                             f"at least {MIN_SIDE} px on the short side after downscaling to "
                             f"{max_side} px on the long side (a face cannot be found below that)",
                             f"{w}x{h} px, {new_w}x{new_h} px after downscaling")

    return Photo(image=rgb, path=source, scale=scale, original_size=(w, h), notes=tuple(notes), opacity=opacity)


def _opacity(array: np.ndarray) -> np.ndarray | None:
    """(H, W) float32 alpha in [0, 1] of a grey+alpha or RGBA array, None if it is opaque."""
    if array.ndim != 3 or array.shape[2] not in (2, 4):
        return None
    alpha = array[:, :, -1]
    top = float(np.iinfo(alpha.dtype).max) if np.issubdtype(alpha.dtype, np.integer) else 1.0
    opacity = np.clip(alpha.astype(np.float32) / top, 0.0, 1.0)
    return None if bool((opacity >= 1.0).all()) else np.ascontiguousarray(opacity)


def _check_file(p: Path, source: str) -> None:
    """Raise InputError unless ``p`` is a non-empty regular file."""
    try:
        st = p.stat()
    except FileNotFoundError:
        raise InputError(source, "file", "an existing image file", "no such file") from None
    except NotADirectoryError:
        raise InputError(source, "file", "an existing image file",
                         "a path through something that is not a folder") from None
    except PermissionError:
        raise InputError(source, "file", "a readable image file", "permission denied") from None
    except OSError as exc:
        raise InputError(source, "file", "a readable image file", exc.strerror or str(exc)) from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(source, "file", "an image file", "a directory")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(source, "file", "a regular image file", "a special file (device, FIFO or socket)")
    if st.st_size == 0:
        raise InputError(source, "image", _EXPECTED_IMAGE, "an empty file (0 bytes)")


_Decoded = tuple[np.ndarray, list[str], int, int, str | None]


def _decode(p: Path, source: str) -> _Decoded:
    """Decode the first frame with Pillow: (array, notes, EXIF orientation, frames, ICC note).

    The array is in the file's own depth and layout: (H, W[, C]) uint8/uint16/float32 with
    C in 1..4 (grey, grey+alpha, RGB, RGBA). Orientation is not applied yet.
    """
    with _PIL_LOCK:
        saved = ImageFile.LOAD_TRUNCATED_IMAGES
        ImageFile.LOAD_TRUNCATED_IMAGES = False
        try:
            return _decode_locked(p, source)
        finally:
            ImageFile.LOAD_TRUNCATED_IMAGES = saved


def _decode_locked(p: Path, source: str) -> _Decoded:
    _register_formats(_head(p))
    formats = [f for f in _FORMATS if f in Image.OPEN]
    try:
        with Image.open(p, formats=formats) as im:
            w, h = im.size
            if min(w, h) < MIN_SIDE:
                raise InputError(source, "image size",
                                 f"at least {MIN_SIDE} px on the short side "
                                 "(a face cannot be found below that)", f"{w}x{h} px")
            frames = int(getattr(im, "n_frames", 1) or 1)
            # 16-bit colour is truncated to its high byte by Pillow; remember it before load()
            # (which clears ``tile``) and decode those samples again with OpenCV.
            wide_colour = im.mode in ("RGB", "RGBA") and any(
                ";16" in str(t.args) for t in (im.tile or []))
            im.load()
            orientation = _orientation(im)
            icc_note = _icc_note(im)
            array, notes = _pil_pixels(im, source)
            if wide_colour:
                array = _decode_16bit_colour(p, (w, h), array)
    except InputError:
        raise
    except Image.DecompressionBombError as exc:
        raise InputError(source, "image", "an image of at most "
                         f"{Image.MAX_IMAGE_PIXELS} pixels (decompression-bomb limit)",
                         f"a decompression bomb ({exc})") from None
    except Image.UnidentifiedImageError:
        raise InputError(source, "image", _EXPECTED_IMAGE,
                         f"unrecognised data starting with {_head(p)!r}") from None
    except PermissionError:
        raise InputError(source, "file", "a readable image file", "permission denied") from None
    except MemoryError:
        raise InputError(source, "image", "an image that fits in memory",
                         "not enough memory to decode it") from None
    except Exception as exc:  # Pillow raises OSError, SyntaxError, ValueError, EOFError, ...
        reason = str(exc) or type(exc).__name__
        raise InputError(source, "image", _EXPECTED_IMAGE,
                         f"a truncated or corrupt file ({reason})") from None
    return array, notes, orientation, frames, icc_note


@functools.cache
def _register_formats(head: bytes) -> None:
    """Import the Pillow plugin of a file starting with ``head`` when :data:`_SIGNATURE_PLUGINS`
    knows its signature, else all plugins of :data:`_FORMATS` (a plugin this Pillow lacks, e.g.
    AVIF before 11.2, is skipped: its format is then not offered)."""
    known = [name for signature, name in _SIGNATURE_PLUGINS if head.startswith(signature)]
    for name in known or _PLUGINS:
        try:
            importlib.import_module(f"PIL.{name}")
        except ImportError:
            pass


def _head(p: Path, n: int = 16) -> bytes:
    try:
        with open(p, "rb") as f:
            return f.read(n)
    except OSError:  # pragma: no cover - it was readable a moment ago
        return b""


def _orientation(im: Image.Image) -> int:
    """The EXIF (or XMP) orientation, 1 when absent, unreadable or out of range."""
    try:
        value = int(im.getexif().get(0x0112, 1))
    except Exception:
        return 1
    return value if 1 <= value <= 8 else 1


def _icc_note(im: Image.Image) -> str | None:
    profile = im.info.get("icc_profile")
    if not profile:
        return None
    try:
        import io

        from PIL import ImageCms

        desc = ImageCms.getProfileDescription(ImageCms.ImageCmsProfile(io.BytesIO(profile))).strip()
    except Exception:
        return "embedded ICC profile not applied (pixels used as stored)"
    if "srgb" in desc.lower().replace(" ", ""):
        return None
    return f"embedded ICC profile {desc!r} not applied (pixels used as stored, treated as sRGB)"


def _pil_pixels(im: Image.Image, source: str) -> tuple[np.ndarray, list[str]]:
    """The loaded frame as a numpy array in the file's depth, plus notes on mode conversions."""
    mode = im.mode
    notes: list[str] = []
    if mode == "1":
        im = im.convert("L")
        notes.append("1-bit image expanded to 8 bit")
    elif mode in ("P", "PA"):
        has_alpha = mode == "PA" or "transparency" in im.info
        im = im.convert("RGBA" if has_alpha else "RGB")
        notes.append("palette image expanded to RGB")
    elif mode == "CMYK":
        im = im.convert("RGB")
        notes.append("CMYK converted to RGB")
    elif mode == "La":
        im = im.convert("LA")
    elif mode == "RGBa":
        im = im.convert("RGBA")
    elif mode in ("RGBX", "YCbCr", "HSV", "LAB"):
        try:
            im = im.convert("RGB")
        except ValueError:
            raise InputError(source, "image colour mode", "RGB, greyscale, palette or CMYK",
                             mode) from None
        if mode != "RGBX":
            notes.append(f"{mode} converted to RGB")

    arr = np.asarray(im)
    if im.mode.startswith("I;16"):
        arr = arr.astype(np.uint16)  # native byte order (I;16B arrives big-endian)
    elif im.mode == "I":
        lo, hi = (int(arr.min()), int(arr.max())) if arr.size else (0, 0)
        if lo < 0 or hi > 65535:
            raise InputError(source, "image values", "integer samples in [0, 65535]",
                             f"32-bit integer samples in [{lo}, {hi}]")
        arr = arr.astype(np.uint16)
    elif im.mode == "F":
        arr = arr.astype(np.float32)
    elif arr.dtype != np.uint8:
        raise InputError(source, "image colour mode", "an 8- or 16-bit image", f"{im.mode}")
    return arr, notes


def _decode_16bit_colour(p: Path, size: tuple[int, int], fallback: np.ndarray) -> np.ndarray:
    """16-bit RGB(A) samples via OpenCV (which ignores EXIF orientation with IMREAD_UNCHANGED).

    Pillow keeps only the high byte of 16-bit colour samples. Returns ``fallback`` (Pillow's
    8-bit pixels) when OpenCV cannot decode the file or disagrees on its size or channels.
    """
    try:
        with silenced_native_stderr():  # libpng's own "libpng error: ..." line
            arr = cv2.imdecode(np.fromfile(p, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except Exception:  # pragma: no cover - cv2 errors on odd files
        return fallback
    if (arr is None or arr.dtype != np.uint16 or arr.ndim != 3 or arr.shape[1::-1] != size
            or arr.shape[2] != fallback.shape[2]):
        return fallback
    order = [2, 1, 0] if arr.shape[2] == 3 else [2, 1, 0, 3]
    return np.ascontiguousarray(arr[:, :, order])


def _apply_orientation(arr: np.ndarray, orientation: int) -> np.ndarray:
    """Undo EXIF orientation 2..8 on an (H, W, C) array, as ``PIL.ImageOps.exif_transpose``."""
    if orientation == 2:
        return arr[:, ::-1]
    if orientation == 3:
        return arr[::-1, ::-1]
    if orientation == 4:
        return arr[::-1]
    if orientation == 5:
        return arr.swapaxes(0, 1)
    if orientation == 6:
        return np.rot90(arr, -1)  # 90° clockwise
    if orientation == 7:
        return arr[::-1, ::-1].swapaxes(0, 1)
    if orientation == 8:
        return np.rot90(arr, 1)  # 90° counter-clockwise
    return arr
