"""A clip's observed frames, kept in an unnamed temporary file rather than in memory.

:func:`facegeo.tracking.observe_frames` observes every frame of a clip before the identity is
fitted to its keyframes and every frame is solved with that identity, so what it observed has to
be kept until then. In memory that grew with the clip (33 KB a frame: 60 MB a minute at 30
frames/s); here each frame is one fixed-size record of a file that has no name
(:func:`tempfile.TemporaryFile`: O_TMPFILE on Linux, unlinked at once elsewhere), so memory stays
the same however long the clip, and the file is gone when the process ends, however it ends
(Ctrl-C, a kill, a crash). Records are written and read with ``pwrite``/``pread`` at their own
offsets, so a forked child that inherits the store (:mod:`facegeo.forked_call`) reads it, or
fills one made for it before the fork, without disturbing the caller's.

A record holds what the per-frame solve and the identity fit read of a frame
(:class:`ObservedFrame`): its number and time, the 88 landmarks and their weights, the dense
points with their weights and flags, the camera, the lid gaps, and the note of a frame without a
face; float64 and the original dtypes are restored on reading, so a clip's solve is the same bit
for bit as from the observations themselves. The dense points' model correspondence (vertex ids
and barycentric weights, the same for every frame) is the store's, in memory.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import overload

import numpy as np

from facegeo.camera import Camera
from facegeo.errors import OutputError
from facegeo.fitting.landmark_problem import SurfacePoints
from facegeo.fitting.photo_fit import PhotoObservation
from facegeo.landmarks.scheme import N_LANDMARKS
from facegeo.morphable_model import MorphableModel
from facegeo.staged_output import WRITE_FAULTS

__all__ = ["ObservedFrame", "ObservedFrames", "NOTE_BYTES"]

#: Bytes of a frame's note (UTF-8; a longer one is cut at a character boundary).
NOTE_BYTES = 256
#: The header's float64 fields: index, time, flags, focal, cx, cy, width, height, lid gap right, left.
_HEADER = 10
_HAS_FACE, _HAS_SURFACE, _HAS_WEIGHTS, _HAS_GAPS, _FOCAL_KNOWN, _FOLLOWED_BACK = 1, 2, 4, 8, 16, 32


@dataclass(frozen=True)
class ObservedFrame:
    """A frame as observed (:func:`facegeo.tracking.observe_frames`): ``index`` and ``time_s``
    as the source's frame, the ``observation`` without its pixels (None when no face was found)
    and ``note``, why; ``lid_gaps`` (2,) px, the subject's right and left eye's lid gap read by
    the iris model (:func:`facegeo.landmarks.eyelids.lid_gaps`; NaN for an eye it could not
    read), None without a face or for a model without
    :data:`~facegeo.landmarks.eyelids.BLINK_NAMES`; ``followed_back``: the face was lost going
    forward and found by following the next frame's face back into this one (a hand or motion
    blur over it: :meth:`facegeo.tracking._FrameObserver.observe`)."""

    index: int
    time_s: float
    observation: PhotoObservation | None
    note: str | None = None
    lid_gaps: np.ndarray | None = None
    followed_back: bool = False


class ObservedFrames(Sequence[ObservedFrame]):
    """The observed frames of one clip (or one part of it), in order, in an unnamed temporary
    file (module docstring): ``append``, ``extend``, ``len``, indexing and iteration, as a list
    of :class:`ObservedFrame`. ``model`` and ``source``: what the observations read back carry;
    ``correspondence``: the dense points' vertex ids (K, 3) and barycentric weights (K, 3) on the
    model, the same for every frame (None: frames have no dense points). :meth:`close` (or the
    end of the process) frees the file.

    A forked child may fill a store made before the fork (:meth:`append`, then return); the
    caller then takes its records with :meth:`sync`. A write that fails for want of room (a full
    temporary file system) raises :class:`~facegeo.errors.OutputError` naming the temporary folder."""

    def __init__(self, model: MorphableModel, source: str, correspondence: tuple[np.ndarray, np.ndarray] | None):
        self.model, self.source, self.correspondence = model, source, correspondence
        self.points = 0 if correspondence is None else len(correspondence[0])
        self._floats = _HEADER + N_LANDMARKS * 3 + self.points * 5
        self._record = self._floats * 8 + NOTE_BYTES
        self._file = tempfile.TemporaryFile(prefix="facegeo-observed-")
        self._count = 0

    def sync(self) -> ObservedFrames:
        """Take the whole records in the file as this store's frames (those a forked child that
        shares the file appended; a record cut short by the child's end is left out and
        overwritten by the next :meth:`append`); returns this store."""
        self._count = os.fstat(self._file.fileno()).st_size // self._record
        return self

    def clear(self) -> ObservedFrames:
        """Drop every frame (the file emptied); returns this store."""
        self._file.truncate(0)
        self._count = 0
        return self

    def __len__(self) -> int:
        return self._count

    @overload
    def __getitem__(self, k: int) -> ObservedFrame: ...

    @overload
    def __getitem__(self, k: slice) -> list[ObservedFrame]: ...

    def __getitem__(self, k: int | slice) -> ObservedFrame | list[ObservedFrame]:
        if isinstance(k, slice):
            return [self[j] for j in range(*k.indices(self._count))]
        if k < 0:
            k += self._count
        if not 0 <= k < self._count:
            raise IndexError(f"frame {k} of {self._count}")
        return self._decode(os.pread(self._file.fileno(), self._record, k * self._record))

    def __iter__(self) -> Iterator[ObservedFrame]:
        for k in range(self._count):
            yield self[k]

    def append(self, frame: ObservedFrame) -> None:
        """Write ``frame`` as the next record."""
        self._write(self._encode(frame), self._count)
        self._count += 1

    def extend(self, frames: Iterable[ObservedFrame]) -> ObservedFrames:
        """Append ``frames`` (another store's records are copied as they are, then its file
        closed); returns this store."""
        if isinstance(frames, ObservedFrames) and frames._record == self._record:
            for k in range(len(frames)):
                self._write(os.pread(frames._file.fileno(), frames._record, k * frames._record), self._count)
                self._count += 1
            frames.close()
        else:
            for frame in frames:
                self.append(frame)
        return self

    def close(self) -> None:
        """Free the file (the store is empty afterwards)."""
        self._file.close()
        self._count = 0

    def _write(self, data: bytes, k: int) -> None:
        try:
            written = os.pwrite(self._file.fileno(), data, k * self._record)
        except OSError as error:
            if error.errno in WRITE_FAULTS:
                raise OutputError(tempfile.gettempdir(), f"{WRITE_FAULTS[error.errno]} (a clip's observations are kept there, "
                                  f"{self._record // 1024} KB a frame; set TMPDIR to a folder with room)") from None
            raise
        if written != len(data):
            raise OutputError(tempfile.gettempdir(), f"a short write ({written} of {len(data)} bytes)")

    def _encode(self, frame: ObservedFrame) -> bytes:
        values = np.zeros(self._floats, np.float64)
        flags = 0
        obs = frame.observation
        values[0], values[1] = frame.index, frame.time_s
        if frame.lid_gaps is not None:
            flags |= _HAS_GAPS
            values[8:10] = frame.lid_gaps
        if frame.followed_back:
            flags |= _FOLLOWED_BACK
        at = _HEADER
        if obs is not None:
            flags |= _HAS_FACE | (_FOCAL_KNOWN if obs.camera.focal_known else 0)
            camera = obs.camera
            values[3:8] = camera.focal, camera.cx, camera.cy, camera.width, camera.height
            values[at:at + 2 * N_LANDMARKS] = np.asarray(obs.landmarks, np.float64).ravel()
            if obs.weights is not None:
                flags |= _HAS_WEIGHTS
                values[at + 2 * N_LANDMARKS:at + 3 * N_LANDMARKS] = obs.weights
            surface = obs.surface_points
            if surface is not None:
                kept = self.correspondence
                if kept is None or not (surface.vertex_ids is kept[0] or np.array_equal(surface.vertex_ids, kept[0])) or not (
                        surface.barycentric is kept[1] or np.array_equal(surface.barycentric, kept[1])):
                    raise ValueError("a frame's dense points sit elsewhere on the model than the store's correspondence")
                flags |= _HAS_SURFACE
                dense = values[at + 3 * N_LANDMARKS:].reshape(5, self.points)
                dense[0:2] = surface.targets.T
                dense[2], dense[3], dense[4] = surface.weights, surface.contour, surface.expressive
        values[2] = flags
        note = (frame.note or "").encode("utf-8")[:NOTE_BYTES].decode("utf-8", "ignore").encode("utf-8")
        return values.tobytes() + note.ljust(NOTE_BYTES, b"\0")

    def _decode(self, data: bytes) -> ObservedFrame:
        values = np.frombuffer(data, np.float64, self._floats)
        flags = int(values[2])
        note = data[self._floats * 8:].rstrip(b"\0").decode("utf-8") or None
        gaps = values[8:10].copy() if flags & _HAS_GAPS else None
        observation = None
        if flags & _HAS_FACE:
            at = _HEADER
            focal, cx, cy, width, height = values[3:8]
            camera = Camera(float(focal), float(cx), float(cy), int(width), int(height), bool(flags & _FOCAL_KNOWN))
            landmarks = values[at:at + 2 * N_LANDMARKS].reshape(N_LANDMARKS, 2).copy()
            weights = values[at + 2 * N_LANDMARKS:at + 3 * N_LANDMARKS].astype(np.float32) if flags & _HAS_WEIGHTS else None
            surface = None
            if flags & _HAS_SURFACE:
                dense = values[at + 3 * N_LANDMARKS:].reshape(5, self.points)
                vertex_ids, barycentric = self.correspondence
                surface = SurfacePoints(dense[0:2].T.copy(), vertex_ids, barycentric, dense[2].copy(), dense[3] > 0.5, dense[4] > 0.5)
            empty = np.zeros((0, 0, 3), np.uint8)
            observation = PhotoObservation(empty, self.source, empty, self.model, landmarks, camera, None, weights, surface, {}, [])
        return ObservedFrame(int(values[0]), float(values[1]), observation, note, gaps, bool(flags & _FOLLOWED_BACK))
