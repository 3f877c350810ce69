"""The frames of a video, one at a time: a video file, an animated GIF or a folder of frames.

:func:`open_video` checks the source and the range at once and returns its :class:`VideoInfo`
with a lazy iterator of :class:`Frame` (one decoded frame in memory at a time, whatever the
clip's length). Sources:

* a video file that OpenCV's FFmpeg backend reads (mp4, mov, avi, webm, mkv, ...); its rate is
  the container's (``CAP_PROP_FPS``; 30.0 when the file records none);
* an animated GIF (Pillow): the rate is 1000 / the median of the frames' durations in ms (30.0
  when no frame has a duration); frames composited over white where transparent;
* a folder of numbered frames: image files (PNG, JPEG, TIFF, BMP, WebP, PPM, GIF) whose name
  holds a number, sorted by the last number in the name (``frame_2.png`` before
  ``frame_10.png``), decoded by :func:`facegeo.photo.load_photo` (EXIF orientation applied, no
  downscaling); the frame's index is its place in that order; the rate is 30.0.

``fps=`` overrides the rate of any source. A frame's time is ``index / fps`` seconds from the
source's start, also for a GIF whose frames have different durations.

Bad input is one :class:`facegeo.errors.InputError` naming the path (a missing path, a file
that is no video, a folder without numbered frames, an invalid ``--start``/``--end``/``--every``/
``--fps``, an empty range), raised by :func:`open_video` itself. While iterating, a folder's frame
that cannot be decoded or differs in size from the first frame read raises an ``InputError``
naming that frame's file; a video file whose frame fails to decode mid-way simply ends there (the
caller may compare the frames it got with ``VideoInfo.frame_count``).
"""

from __future__ import annotations

import math
import os
import re
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from facegeo.errors import InputError

__all__ = ["VideoInfo", "Frame", "open_video", "DEFAULT_FPS", "FRAME_SUFFIXES"]

#: The rate of a source that records none (a folder of frames, a GIF without durations).
DEFAULT_FPS = 30.0
#: File name endings of the frames in a folder of frames (case-insensitive).
FRAME_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp", ".ppm", ".gif")
_EXPECTED_VIDEO = "a video (mp4, mov, avi, webm, mkv), an animated GIF or a folder of numbered frames"
_NUMBER = re.compile(r"\d+")
_IMAGE_FORMATS = ("PNG", "JPEG", "TIFF", "BMP", "WEBP", "PPM")  # images refused as a video file
_NO_DOWNSCALE = 1 << 30  # load_photo's max_side for frames kept at their own size


@dataclass(frozen=True)
class VideoInfo:
    """What a source is.

    Attributes:
        source: the path as given.
        fps: frames per second (the container's rate; a GIF's from its median frame duration; a
            folder of frames or a source that records none: 30.0; ``fps=`` of :func:`open_video`
            when given).
        frame_count: frames in the source if known (a video file's count is the container's
            figure, which may be an estimate), else None.
        width: pixels of a frame's row.
        height: rows of a frame, pixels.
        notes: what the user should know of how the source was read (a rate assumed, gaps in a
            folder's numbering).
    """

    source: str
    fps: float
    frame_count: int | None
    width: int
    height: int
    notes: tuple[str, ...] = ()


@dataclass(frozen=True, eq=False)
class Frame:
    """One decoded frame.

    Attributes:
        index: the frame's number in the source (0-based).
        time_s: ``index / fps``, seconds from the source's start.
        image: (H, W, 3) uint8 RGB, C-contiguous.

    Equality is identity (``eq=False``), as :class:`facegeo.photo.Photo`'s.
    """

    index: int
    time_s: float
    image: np.ndarray


def open_video(path: str | os.PathLike[str], start_s: float | None = None, end_s: float | None = None,
               every: int = 1, fps: float | None = None) -> tuple[VideoInfo, Iterator[Frame]]:
    """Open a video file, an animated GIF or a folder of numbered frames (module docstring).

    Args:
        path: the source.
        start_s: keep frames with ``time_s >= start_s`` (seconds, >= 0; None: from the start).
        end_s: keep frames with ``time_s < end_s`` (seconds, > ``start_s``; None: to the end).
        every: keep every N-th of those frames (N >= 1), counted from the first kept frame.
        fps: frames per second to use instead of the source's (> 0; None: the source's).
    Returns:
        (info, frames): ``frames`` decodes lazily, in order; the first kept frame is decoded
        here already (it gives the size and proves the range is not empty).
    Raises:
        InputError: (``path``, field, ...) for a missing path, a file that is not a readable
            video or animated GIF, a folder without numbered image frames, an invalid
            ``--start``/``--end``/``--every``/``--fps``, or no frame in the range.
    """
    source = os.fspath(path)
    start, end, every, rate = _check_range(source, start_s, end_s, every, fps)
    p = Path(source)
    try:
        is_dir = p.is_dir()
        exists = is_dir or p.exists()
    except OSError as exc:
        raise InputError(source, "file", _EXPECTED_VIDEO, exc.strerror or str(exc)) from None
    if not exists:
        raise InputError(source, "file", _EXPECTED_VIDEO, "no such file or folder")
    if is_dir:
        return _open_folder(source, p, start, end, every, rate)
    if _head(p, source).startswith((b"GIF87a", b"GIF89a")):
        return _open_gif(source, p, start, end, every, rate)
    return _open_capture(source, p, start, end, every, rate)


# --------------------------------------------------------------------------------------------
# The range
# --------------------------------------------------------------------------------------------


def _check_range(source: str, start_s: Any, end_s: Any, every: Any, fps: Any) -> tuple[float, float, int, float | None]:
    """(start, end, every, fps) checked: start in [0, inf), end in (start, inf) (inf where not
    given), every >= 1."""
    def number(value: Any, field: str, expected: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise InputError(source, field, expected, repr(value))
        value = float(value)
        if math.isnan(value):
            raise InputError(source, field, expected, "nan")
        return value

    start = 0.0 if start_s is None else number(start_s, "--start", "seconds >= 0")
    if not (math.isfinite(start) and start >= 0):
        raise InputError(source, "--start", "seconds >= 0", repr(start_s))
    end = math.inf if end_s is None else number(end_s, "--end", f"seconds > the start ({start:g} s)")
    if not (end > start and (end_s is None or math.isfinite(end))):
        raise InputError(source, "--end", f"seconds > the start ({start:g} s)", repr(end_s))
    if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or every < 1:
        raise InputError(source, "--every", "a whole number of frames >= 1", repr(every))
    rate = None
    if fps is not None:
        rate = number(fps, "--fps", "frames per second > 0")
        if not (math.isfinite(rate) and rate > 0):
            raise InputError(source, "--fps", "frames per second > 0", repr(fps))
    return start, end, int(every), rate


def _index_range(start: float, end: float, fps: float) -> tuple[int, int | None]:
    """(first, stop) frame indices with ``start <= i / fps < end`` (stop None: no end), exactly
    as :class:`Frame` computes ``time_s``; a time beyond every index (``start * fps`` or
    ``end * fps`` overflows) starts after any source's last frame, or has no end."""
    if not math.isfinite(start * fps):
        return sys.maxsize, sys.maxsize
    first = max(0, math.floor(start * fps) - 1)
    while first / fps < start:
        first += 1
    if not math.isfinite(end * fps):
        return first, None
    stop = max(first, math.floor(end * fps) - 1)
    while stop / fps < end:
        stop += 1
    return first, stop


def _assumed_rate(why: str) -> str:
    return f"{why}: {DEFAULT_FPS:g} frames per second assumed (--fps gives the rate)"


def _empty_range(source: str, start: float, end: float, fps: float, count: int | None) -> InputError:
    if count is not None and start >= count / fps:
        length = f"{count} frames, {count / fps:g} s at {fps:g} frames per second"
        return InputError(source, "--start", f"a time before the source's end ({length})", f"{start:g} s")
    span = f"in [{start:g}, {end:g}) s" if math.isfinite(end) else f"from {start:g} s on"
    return InputError(source, "--start/--end", f"a range holding at least one frame (frames every {1 / fps:g} s)", f"no frame {span}")


def _frames(first: Frame, rest: Iterator[tuple[int, np.ndarray]], fps: float, close: Callable[[], None]) -> Iterator[Frame]:
    """The kept frames: ``first``, then ``rest``'s (each source's ``rest`` yields only the kept
    indices, every ``every``-th before the range's end), the source closed at the end."""
    try:
        yield first
        for index, image in rest:
            yield Frame(index, index / fps, image)
    finally:
        close()


# --------------------------------------------------------------------------------------------
# Sources
# --------------------------------------------------------------------------------------------


def _head(p: Path, source: str, n: int = 16) -> bytes:
    try:
        with open(p, "rb") as handle:
            return handle.read(n)
    except PermissionError:
        raise InputError(source, "file", "a readable file", "permission denied") from None
    except OSError as exc:
        raise InputError(source, "file", _EXPECTED_VIDEO, exc.strerror or str(exc)) from None


def _open_capture(source: str, p: Path, start: float, end: float, every: int,
                  rate: float | None) -> tuple[VideoInfo, Iterator[Frame]]:
    """A video file through OpenCV's FFmpeg backend."""
    import cv2

    from facegeo.native_stderr import silenced_native_stderr

    still = _still_image_format(p)
    if still is not None:
        raise InputError(source, "file", _EXPECTED_VIDEO, f"a single {still} image" if " " not in still else f"a {still}")
    cap = None
    try:
        with silenced_native_stderr():  # FFmpeg's own complaints about a file it cannot read
            cap = cv2.VideoCapture(str(p), cv2.CAP_FFMPEG)
            opened = cap.isOpened()
            if opened:
                native_fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
                recorded = math.isfinite(native_fps) and native_fps > 0
                count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
                fps = rate or (native_fps if recorded else DEFAULT_FPS)
                frame_count = count if count > 0 else None
                first, stop = _index_range(start, end, fps)
                image = None
                if (frame_count is None or first < frame_count) and (stop is None or first < stop):
                    image = _seek_and_read(cap, first)
                    if image is None and first == 0:
                        opened = False  # not even the first frame decodes: no video
    except Exception as exc:  # cv2.error on odd files: bad input, never a traceback
        if cap is not None:
            cap.release()
        raise InputError(source, "video", _EXPECTED_VIDEO, f"a file OpenCV cannot read ({exc})") from None
    if not opened:
        cap.release()
        raise InputError(source, "video", _EXPECTED_VIDEO, f"a file neither OpenCV (FFmpeg) nor Pillow can read ({_head(p, source)!r}...)")
    if image is None:
        cap.release()
        raise _empty_range(source, start, end, fps, frame_count)
    height, width = image.shape[:2]
    assumed = () if rate or recorded else (_assumed_rate("the video records no frame rate"),)
    info = VideoInfo(source, float(fps), frame_count, int(width), int(height), assumed)

    def rest() -> Iterator[tuple[int, np.ndarray]]:
        index = first
        while True:
            index += 1
            if stop is not None and index >= stop:
                return
            if (index - first) % every:
                if not cap.grab():  # skipped: demuxed, not converted
                    return
                continue
            ok, bgr = cap.read()
            if not ok or bgr is None:
                return
            yield index, _rgb(cv2, bgr)

    return info, _frames(Frame(first, first / fps, image), rest(), fps, cap.release)


def _seek_and_read(cap: Any, first: int) -> np.ndarray | None:
    """Frame ``first`` as RGB (None if the video ends before it): a seek where the backend lands
    exactly, else reading from the start."""
    import cv2

    if first > 0:
        cap.set(cv2.CAP_PROP_POS_FRAMES, first)
        if int(round(cap.get(cv2.CAP_PROP_POS_FRAMES))) != first:
            cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            for _ in range(first):
                if not cap.grab():
                    return None
    ok, bgr = cap.read()
    return _rgb(cv2, bgr) if ok and bgr is not None else None


def _rgb(cv2: Any, frame: np.ndarray) -> np.ndarray:
    """OpenCV's BGR (or grey) frame as (H, W, 3) uint8 RGB, C-contiguous."""
    if frame.ndim == 2:
        frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2RGB)
    elif frame.shape[2] == 4:
        frame = cv2.cvtColor(frame, cv2.COLOR_BGRA2RGB)
    else:
        frame = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
    if frame.dtype != np.uint8:
        frame = (frame >> 8).astype(np.uint8) if frame.dtype == np.uint16 else frame.astype(np.uint8)
    return np.ascontiguousarray(frame)


def _still_image_format(p: Path) -> str | None:
    """The format of an image file Pillow recognises (PNG, JPEG, ...; not GIF), else None."""
    from PIL import Image

    try:
        Image.init()
        with Image.open(p, formats=[f for f in _IMAGE_FORMATS if f in Image.OPEN]) as im:
            frames = int(getattr(im, "n_frames", 1) or 1)
            return str(im.format) if frames == 1 else f"{im.format} animation (of the animations, only GIFs are read)"
    except Exception:
        return None


def _open_gif(source: str, p: Path, start: float, end: float, every: int,
              rate: float | None) -> tuple[VideoInfo, Iterator[Frame]]:
    """An animated GIF through Pillow, frame by frame."""
    from PIL import Image

    def bad(exc: Exception) -> InputError:
        return InputError(source, "video", _EXPECTED_VIDEO, f"a truncated or corrupt GIF ({exc or type(exc).__name__})")

    try:
        im = Image.open(p, formats=["GIF"])
    except Exception as exc:
        raise bad(exc) from None
    try:
        count = int(getattr(im, "n_frames", 1) or 1)
        durations = []
        for i in range(count):
            im.seek(i)
            duration = im.info.get("duration")
            if isinstance(duration, (int, float)) and duration > 0:
                durations.append(float(duration))
        fps = rate or (1000.0 / statistics.median(durations) if durations else DEFAULT_FPS)
        first, stop = _index_range(start, end, fps)
        if first >= count or (stop is not None and first >= stop):
            raise _empty_range(source, start, end, fps, count)
        image = _gif_frame(im, first, source)
    except InputError:
        im.close()
        raise
    except Exception as exc:
        im.close()
        raise bad(exc) from None
    height, width = image.shape[:2]
    info = VideoInfo(source, float(fps), count, int(width), int(height))

    def rest() -> Iterator[tuple[int, np.ndarray]]:
        last = count if stop is None else min(count, stop)
        for index in range(first + every, last, every):
            try:
                yield index, _gif_frame(im, index, source)
            except InputError:
                raise
            except Exception:  # a corrupt frame mid-way: the clip ends there
                return

    return info, _frames(Frame(first, first / fps, image), rest(), fps, im.close)


def _gif_frame(im: Any, index: int, source: str) -> np.ndarray:
    """Frame ``index`` of an open GIF as (H, W, 3) uint8 RGB, transparency over white."""
    from facegeo.photo import as_rgb_uint8

    im.seek(index)
    return as_rgb_uint8(np.asarray(im.convert("RGBA")), source)


def _open_folder(source: str, p: Path, start: float, end: float, every: int,
                 rate: float | None) -> tuple[VideoInfo, Iterator[Frame]]:
    """A folder of numbered image frames, each read with :func:`facegeo.photo.load_photo`."""
    from facegeo.photo import load_photo

    try:
        names = os.listdir(p)
    except OSError as exc:
        raise InputError(source, "folder", "a readable folder of numbered frames", exc.strerror or str(exc)) from None
    numbered: dict[int, str] = {}
    for name in names:
        stem, suffix = os.path.splitext(name)
        numbers = _NUMBER.findall(stem)
        if name.startswith(".") or suffix.lower() not in FRAME_SUFFIXES or not numbers:
            continue
        number = int(numbers[-1])
        if number in numbered:
            a, b = sorted((numbered[number], name))
            raise InputError(source, "frames", "one image file per frame number", f"{a} and {b} both numbered {number}")
        numbered[number] = name
    if not numbered:
        raise InputError(source, "frames", f"{_EXPECTED_VIDEO} (image files {', '.join(FRAME_SUFFIXES)} "
                         "with a number in the name, e.g. frame_0001.png)", "no numbered image files")
    numbers = sorted(numbered)
    files = [p / numbered[k] for k in numbers]
    fps = rate or DEFAULT_FPS
    first, stop = _index_range(start, end, fps)
    if first >= len(files) or (stop is not None and first >= stop):
        raise _empty_range(source, start, end, fps, len(files))
    image = load_photo(files[first], max_side=_NO_DOWNSCALE).image
    height, width = image.shape[:2]
    gaps = [(a + 1, b - 1) for a, b in zip(numbers, numbers[1:]) if b > a + 1]
    notes = () if rate else (_assumed_rate("a folder of frames records no frame rate"),)
    if gaps:
        shown = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in gaps[:3]) + (f" and {len(gaps) - 3} more gaps" if len(gaps) > 3 else "")
        notes += (f"frame numbers {shown} missing: the frames are timed one after another, as if none were missing",)
    info = VideoInfo(source, float(fps), len(files), int(width), int(height), notes)

    def rest() -> Iterator[tuple[int, np.ndarray]]:
        last = len(files) if stop is None else min(len(files), stop)
        for index in range(first + every, last, every):
            frame = load_photo(files[index], max_side=_NO_DOWNSCALE).image
            if frame.shape != image.shape:
                raise InputError(str(files[index]), "image size", f"{width}x{height} px, the size of the first frame "
                                 f"({files[first].name})", f"{frame.shape[1]}x{frame.shape[0]} px")
            yield index, frame

    return info, _frames(Frame(first, first / fps, image), rest(), fps, lambda: None)
