"""Live Link Face recordings: the CSV that Epic's Live Link Face app exports for a take.

The file (one header row, one row per captured frame)::

    Timecode,BlendShapeCount,EyeBlinkLeft,EyeLookDownLeft,...,TongueOut,HeadYaw,HeadPitch,HeadRoll,
        LeftEyeYaw,LeftEyePitch,LeftEyeRoll,RightEyeYaw,RightEyePitch,RightEyeRoll
    12:24:24:19.960,61,0.0179804321,0.2226290256,...

* ``Timecode``: ``HH:MM:SS:FF`` or ``HH:MM:SS:FF.fff`` (SMPTE time code with a fractional frame);
  the frame field counts at the take's time code rate, which the CSV does not record (it is in the
  take's JSON; Live Link Face's default is 60): :func:`read_live_link_csv` takes it as ``fps``.
  Times are relative to the first row and must increase.
* ``BlendShapeCount``: how many values the app sent (61 = 52 shapes + 9 rotations); checked to be
  a whole number, not used.
* The 52 ARKit blendshapes (:data:`facegeo.arkit.ARKIT_NAMES` with a capital first
  letter), weights in [0, 1]. All 52 are required, in any order.
* ``HeadYaw/HeadPitch/HeadRoll`` and ``LeftEye…/RightEye…`` ``Yaw/Pitch/Roll``: rotations in
  radians. Each group of three (head, left eye, right eye) is optional but all or nothing.
  Their signs, measured on a recorded take (a public Live Link Face sample: the eyes turn
  towards the subject's left while ``EyeLookOutLeft``/``EyeLookInRight`` rise and ``LeftEyeYaw``
  and ``RightEyeYaw`` fall; they look up while ``EyeLookUp*`` rise and the pitches fall): a
  positive yaw turns towards the subject's right, a positive pitch looks down. Roll is taken in
  the same mirrored frame (a positive roll tilts the top of the head towards the subject's
  left); no recording checked its sign. :func:`facegeo.export.animation.rotations` turns them
  into rotations in the model's axes.

Bad input gets one :class:`facegeo.errors.InputError` naming the file, the row (the file's line
number, the header is row 1) and the column. Weights outside [0, 1] are an error unless
``clamp=True``, which clamps them and records a note.

:func:`live_link_csv_text` writes a take back in the same layout (the header in
:data:`LIVE_LINK_COLUMNS` order with only the rotation groups the take has, ``Timecode`` as
``HH:MM:SS:FF.fff`` at the take's ``fps``); ``read_live_link_csv(path, fps=take.fps)`` reads it
into the same take (weights exactly, times to a thousandth of a frame, rotations exactly).
"""

from __future__ import annotations

import csv
import math
import os
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from facegeo.arkit import ARKIT_NAMES, ArkitTake
from facegeo.errors import InputError

__all__ = ["read_live_link_csv", "live_link_csv_text", "live_link_csv_lines", "LIVE_LINK_COLUMNS", "ROTATION_GROUPS", "DEFAULT_FPS"]

#: Live Link Face's default time code rate (frames per second of the ``Timecode`` frame field).
DEFAULT_FPS = 60.0
#: The optional rotation columns, by group, each (yaw, pitch, roll) in radians.
ROTATION_GROUPS = {
    "head": ("HeadYaw", "HeadPitch", "HeadRoll"),
    "left_eye": ("LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll"),
    "right_eye": ("RightEyeYaw", "RightEyePitch", "RightEyeRoll"),
}
_SHAPE_COLUMNS = tuple(name[0].upper() + name[1:] for name in ARKIT_NAMES)
#: Every column of a Live Link Face CSV, in the app's order.
LIVE_LINK_COLUMNS = ("Timecode", "BlendShapeCount", *_SHAPE_COLUMNS, *(c for g in ROTATION_GROUPS.values() for c in g))
_TIMECODE = re.compile(r"^(\d{1,2}):(\d{2}):(\d{2})[:;](\d{1,3}(?:\.\d+)?)$")


def read_live_link_csv(path: str | os.PathLike[str], fps: float = DEFAULT_FPS, clamp: bool = False) -> ArkitTake:
    """Read a Live Link Face CSV (module docstring).

    Args:
        path: the CSV file.
        fps: the take's time code rate (frames per second of the ``Timecode`` frame field).
        clamp: clamp weights outside [0, 1] (with a note) instead of refusing the file.
    Raises:
        InputError: an unreadable file, a missing or unknown column, a malformed time code,
            times that do not increase, a value that is not a finite number, a weight outside
            [0, 1] (without ``clamp``), a rotation beyond ±π, or no frames.
    """
    source = Path(path)
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise InputError(source, "fps", "a finite time code rate > 0 (frames per second)", repr(fps))
    try:
        with open(source, newline="", encoding="utf-8-sig") as handle:
            rows = list(csv.reader(handle))
    except FileNotFoundError:
        raise InputError(source, "file", "a Live Link Face CSV", "no such file") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputError(source, "file", "a readable UTF-8 CSV", str(exc)) from None
    while rows and not any(cell.strip() for cell in rows[-1]):
        rows.pop()  # trailing blank lines
    if not rows:
        raise InputError(source, "row 1", "the header row (Timecode,BlendShapeCount,EyeBlinkLeft,...)", "an empty file")
    header = [cell.strip() for cell in rows[0]]
    columns = _columns(source, header)
    data = rows[1:]
    if not data:
        raise InputError(source, "row 2", "at least one frame (an empty take)", "no data rows")
    n = len(data)
    values = np.empty((n, len(header)), dtype=np.float64)
    times = np.empty(n, dtype=np.float64)
    for r, row in enumerate(data):
        line = r + 2
        if len(row) != len(header):
            raise InputError(source, f"row {line}", f"{len(header)} comma-separated values (as the header)", str(len(row)))
        times[r] = _seconds(source, line, row[columns["Timecode"]].strip(), fps)
        for c, cell in enumerate(row):
            if c == columns["Timecode"]:
                continue
            values[r, c] = _number(source, line, header[c], cell)
    count = values[:, columns["BlendShapeCount"]]
    bad = np.flatnonzero((count != np.round(count)) | (count < 0))
    if len(bad):
        raise InputError(source, f"row {bad[0] + 2}, column BlendShapeCount", "a whole number", repr(data[bad[0]][columns["BlendShapeCount"]]))
    steps = np.diff(times)
    if np.any(steps <= 0):
        r = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise InputError(source, f"row {r + 2}, column Timecode", f"a time after the previous row's (at {fps:g} frames per second)",
                         repr(data[r][columns["Timecode"]].strip()))
    weights = values[:, [columns[c] for c in _SHAPE_COLUMNS]]
    notes = []
    outside = (weights < 0.0) | (weights > 1.0)
    if outside.any():
        r, c = (int(i) for i in np.argwhere(outside)[0])
        if not clamp:
            raise InputError(source, f"row {r + 2}, column {_SHAPE_COLUMNS[c]}", "a weight in [0, 1] (or --clamp)", repr(data[r][columns[_SHAPE_COLUMNS[c]]]))
        notes.append(f"{source}: {int(outside.sum())} weights outside [0, 1] clamped (first at row {r + 2}, column {_SHAPE_COLUMNS[c]})")
        weights = np.clip(weights, 0.0, 1.0)
    rotations = {}
    for group, names in ROTATION_GROUPS.items():
        if names[0] not in columns:
            continue
        angles = values[:, [columns[c] for c in names]]
        beyond = np.abs(angles) > math.pi
        if beyond.any():
            r, c = (int(i) for i in np.argwhere(beyond)[0])
            raise InputError(source, f"row {r + 2}, column {names[c]}", "an angle in radians within [-pi, pi]", repr(data[r][columns[names[c]]]))
        rotations[group] = angles
    return ArkitTake(str(source), float(fps), times - times[0], weights.astype(np.float32), rotations, notes)


def _columns(source: Path, header: list[str]) -> dict[str, int]:
    """Column name -> index, after checking the header: no unknown or repeated names, the time
    code, the count and the 52 shapes present, each rotation group complete or absent."""
    known = set(LIVE_LINK_COLUMNS)
    columns: dict[str, int] = {}
    for separator in (";", "\t"):
        if len(header) == 1 and separator in header[0]:  # a spreadsheet's export with another separator
            raise InputError(source, "row 1", "comma-separated columns", f"{separator!r}-separated ones")
    for c, name in enumerate(header):
        if name not in known:
            hint = next((k for k in LIVE_LINK_COLUMNS if k.lower() == name.lower()), None)
            expected = f"the name {hint!r}" if hint else "a Live Link Face column (Timecode, BlendShapeCount, the 52 ARKit shapes, head and eye rotations)"
            raise InputError(source, f"row 1, column {c + 1}", expected, repr(name))
        if name in columns:
            raise InputError(source, f"row 1, column {c + 1}", "each column once", f"a second {name!r}")
        columns[name] = c
    missing = [name for name in ("Timecode", "BlendShapeCount", *_SHAPE_COLUMNS) if name not in columns]
    if missing:
        shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
        raise InputError(source, f"row 1, column {missing[0]}", "Timecode, BlendShapeCount and every Live Link Face blendshape column",
                         f"{len(missing)} missing: {shown}")
    for names in ROTATION_GROUPS.values():
        present = [n for n in names if n in columns]
        if present and len(present) != len(names):
            missing = next(n for n in names if n not in columns)
            raise InputError(source, f"row 1, column {missing}", f"all of {', '.join(names)} or none", f"only {', '.join(present)}")
    return columns


def _seconds(source: Path, line: int, text: str, fps: float) -> float:
    """Seconds of a ``HH:MM:SS:FF[.fff]`` time code at ``fps`` frames per second."""
    match = _TIMECODE.match(text)
    if match is None:
        raise InputError(source, f"row {line}, column Timecode", "a time code HH:MM:SS:FF or HH:MM:SS:FF.fff", repr(text))
    hours, minutes, seconds = (int(match.group(i)) for i in (1, 2, 3))
    frames = float(match.group(4))
    if minutes >= 60 or seconds >= 60 or frames >= math.ceil(fps):
        raise InputError(source, f"row {line}, column Timecode",
                         f"minutes and seconds below 60 and frames below {math.ceil(fps)} (at {fps:g} frames per second)", repr(text))
    return hours * 3600.0 + minutes * 60.0 + seconds + frames / fps


def _number(source: Path, line: int, column: str, cell: str) -> float:
    """A finite number, or an InputError naming the cell."""
    try:
        value = float(cell)
    except ValueError:
        raise InputError(source, f"row {line}, column {column}", "a number", repr(cell)) from None
    if not math.isfinite(value):
        raise InputError(source, f"row {line}, column {column}", "a finite number", repr(cell))
    return value


def live_link_csv_lines(take: ArkitTake, timecode_start_s: float = 0.0) -> Iterator[str]:
    """The CSV text of ``take`` in Live Link Face's layout (module docstring), one line at a time
    (each ending in ``\\n``; the take is checked at the call, the lines made as they are read:
    a long take's file is written without its whole text in memory).

    Args:
        take: the take: ``times`` (N,) seconds, strictly increasing; ``weights`` (N, 52) in
            :data:`ARKIT_NAMES` order, written at float32 precision (``%.9g``, which reads back
            into the same float32); ``rotations`` group -> (N, 3) radians, written exactly
            (shortest round-trip ``repr``); ``fps`` the time code rate of the ``Timecode`` frames.
        timecode_start_s: the time code of ``times == 0`` in seconds from midnight (>= 0).
    Returns:
        The lines: one header row (``Timecode``, ``BlendShapeCount``, the 52 shapes, then the
        take's rotation groups in :data:`ROTATION_GROUPS` order), one row per frame, each line
        ending in ``\\n``. ``Timecode`` is ``HH:MM:SS:FF.fff`` with the time rounded to a
        thousandth of a frame; ``BlendShapeCount`` is 52 + 3 x the number of rotation groups (61
        with all three). :func:`read_live_link_csv` with ``fps=take.fps`` reads it back: weights
        equal, rotations equal, times to within half a thousandth of a frame (exactly, up to
        float rounding, for times on the frame grid).
    Raises:
        ValueError: a malformed take (shapes, an unknown rotation group, non-finite values, times
            that do not increase, a non-positive ``fps``) or a negative or non-finite
            ``timecode_start_s`` (programming errors: a take read or built by facegeo is valid).
    """
    fps = float(take.fps)
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"take.fps must be a finite rate > 0, got {take.fps!r}")
    if not (math.isfinite(timecode_start_s) and timecode_start_s >= 0):
        raise ValueError(f"timecode_start_s must be finite and >= 0, got {timecode_start_s!r}")
    times = np.asarray(take.times, dtype=np.float64)
    weights = np.asarray(take.weights).astype(np.float32)
    n = len(times)
    if times.ndim != 1 or weights.shape != (n, len(_SHAPE_COLUMNS)):
        raise ValueError(f"take.times must be (N,) and take.weights (N, {len(_SHAPE_COLUMNS)}), got {times.shape} and {weights.shape}")
    if n and (not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0)):
        raise ValueError("take.times must be finite and strictly increasing")
    if not np.all(np.isfinite(weights)):
        raise ValueError("take.weights must be finite")
    unknown = set(take.rotations) - set(ROTATION_GROUPS)
    if unknown:
        raise ValueError(f"unknown rotation groups {sorted(unknown)}; expected some of {list(ROTATION_GROUPS)}")
    groups = [g for g in ROTATION_GROUPS if g in take.rotations]
    angles = []
    for g in groups:
        a = np.asarray(take.rotations[g], dtype=np.float64)
        if a.shape != (n, 3) or not np.all(np.isfinite(a)):
            raise ValueError(f"take.rotations[{g!r}] must be a finite (N, 3) = ({n}, 3) array, got shape {a.shape}")
        angles.append(a)
    header = ["Timecode", "BlendShapeCount", *_SHAPE_COLUMNS, *(c for g in groups for c in ROTATION_GROUPS[g])]
    return _rows(header, str(len(_SHAPE_COLUMNS) + 3 * len(groups)), times, weights, angles, timecode_start_s, fps)


def _rows(header: list[str], count: str, times: np.ndarray, weights: np.ndarray, angles: list[np.ndarray], timecode_start_s: float,
          fps: float) -> Iterator[str]:
    """:func:`live_link_csv_lines`' lines of a checked take."""
    yield ",".join(header) + "\n"
    for i in range(len(times)):
        cells = [_timecode(timecode_start_s + float(times[i]), fps), count]
        cells.extend("%.9g" % w for w in weights[i].tolist())
        for a in angles:
            cells.extend(repr(v) for v in a[i].tolist())
        yield ",".join(cells) + "\n"


def live_link_csv_text(take: ArkitTake, timecode_start_s: float = 0.0) -> str:
    """The whole CSV text of ``take`` (:func:`live_link_csv_lines`, joined)."""
    return "".join(live_link_csv_lines(take, timecode_start_s))




def _timecode(t: float, fps: float) -> str:
    """``HH:MM:SS:FF.fff`` of ``t`` seconds at ``fps`` frames per second (the frame field rounded
    to a thousandth of a frame), the inverse of :func:`_seconds`."""
    q = round(t * fps * 1000)  # thousandths of a frame
    if fps == int(fps):
        secs, rem = divmod(q, int(fps) * 1000)
    else:
        secs = int(q // (fps * 1000))
        rem = min(max(q - round(secs * fps * 1000), 0), math.ceil(fps) * 1000 - 1)
    minutes, seconds = divmod(int(secs), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours:02d}:{minutes:02d}:{seconds:02d}:{rem // 1000:02d}.{rem % 1000:03d}"
