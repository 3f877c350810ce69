"""Pluggable, offline landmark detectors producing the 88-point hybrid set.

* ``dlib``: HOG box + dlib's 68-point predictor; the 20 lip points are dlib's own mouth points.
  Non-commercial (iBUG 300-W training data).
* ``mediapipe``: BlazeFace + the 468-point face mesh (Apache-2.0) run with LiteRT; the 68 iBUG
  points come from the documented 468→68 table, the 20 lip points from the mesh. Licence-clean.
* ``hybrid`` (default, the paper's configuration): dlib's 68 + MediaPipe's 20 lip points.

Several faces: the largest is used and a note says so. No face: :class:`NoFaceError`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from facegeo.errors import NoFaceError
from facegeo.landmarks.dlib_detector import DlibLandmarker
from facegeo.landmarks.mediapipe_mesh import MEDIAPIPE_LIPS20, MediaPipeFaceMesh, ibug68_from_mesh
from facegeo.photo import as_rgb_uint8

__all__ = [
    "FaceLandmarks",
    "LandmarkDetector",
    "DlibDetector",
    "MediaPipeDetector",
    "HybridDetector",
    "DETECTORS",
    "get_detector",
    "detect_landmarks",
]


@dataclass(frozen=True)
class FaceLandmarks:
    """Landmarks of one face.

    points: (88, 2) float32, pixels (corner-origin convention of :mod:`facegeo.camera`).
    box: (4,) float32 face box x0, y0, x1, y1 in pixels (same convention).
    n_faces: how many faces the detector found (the largest is the one returned).
    detector: the backend's name. notes: remarks for the user (e.g. several faces).
    """

    points: np.ndarray
    box: np.ndarray
    n_faces: int
    detector: str
    notes: tuple[str, ...] = field(default=())


@runtime_checkable
class LandmarkDetector(Protocol):
    """A detector: ``detect(image (H, W, 3) uint8 RGB, source) -> FaceLandmarks``."""

    name: str

    def detect(self, image: np.ndarray, source: str = "<array>") -> FaceLandmarks: ...


def _several(n: int) -> tuple[str, ...]:
    return (f"{n} faces found; the largest is used",) if n > 1 else ()


def _box_area(box: np.ndarray) -> float:
    return float(max(0.0, box[2] - box[0]) * max(0.0, box[3] - box[1]))


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    inter = np.concatenate([np.maximum(a[:2], b[:2]), np.minimum(a[2:], b[2:])])
    i = _box_area(inter)
    return i / max(_box_area(a) + _box_area(b) - i, 1e-9)


def _corner_origin(points: np.ndarray) -> np.ndarray:
    """dlib/MediaPipe/OpenCV pixel coordinates (pixel centres at integers) -> facegeo's
    corner-origin convention (pixel centres at +0.5), as float32."""
    return (np.asarray(points, dtype=np.float32) + 0.5).astype(np.float32)


def _no_face(source: str, detector: str) -> NoFaceError:
    return NoFaceError(source, f"face ({detector} detector)", "a photo showing one face", "no face")


class DlibDetector:
    """dlib 68 points; the lip points repeat dlib's mouth points 48..67."""

    name = "dlib"

    def __init__(self, landmarker: DlibLandmarker | None = None):
        self.landmarker = landmarker or DlibLandmarker()

    def detect(self, image: np.ndarray, source: str = "<array>") -> FaceLandmarks:
        image = as_rgb_uint8(image, source)
        faces = self.landmarker(image)
        if not faces:
            raise _no_face(source, self.name)
        face = faces[0]
        points = np.concatenate([face.points, face.points[48:68]]).astype(np.float32)
        return FaceLandmarks(points, _corner_origin(face.box), len(faces), self.name, _several(len(faces)))


class MediaPipeDetector:
    """MediaPipe face mesh: 468→68 table + 20 lip points (licence-clean)."""

    name = "mediapipe"

    def __init__(self, mesh: MediaPipeFaceMesh | None = None):
        self.mesh = mesh or MediaPipeFaceMesh()

    def detect(self, image: np.ndarray, source: str = "<array>") -> FaceLandmarks:
        image = as_rgb_uint8(image, source)
        faces = self.mesh(image)
        if not faces:
            raise _no_face(source, self.name)
        face = faces[0]
        points = np.concatenate([ibug68_from_mesh(face.mesh), face.mesh[MEDIAPIPE_LIPS20, :2]])
        return FaceLandmarks(_corner_origin(points), _corner_origin(face.box), len(faces), self.name, _several(len(faces)))


class HybridDetector:
    """The paper's 88 points: dlib's 68 + MediaPipe's 20 lip points.

    The face is MediaPipe's largest; dlib's HOG box for it is the one overlapping it most
    (IoU ≥ 0.3). If HOG misses the face (profiles, small faces), dlib's predictor runs in the box
    spanned by MediaPipe's 68-point estimate, and a note says so. If MediaPipe finds nothing,
    dlib alone is used, with a note.
    """

    name = "hybrid"

    def __init__(self, dlib: DlibDetector | None = None, mediapipe: MediaPipeDetector | None = None):
        self.dlib = dlib or DlibDetector()
        self.mediapipe = mediapipe or MediaPipeDetector()

    def detect(self, image: np.ndarray, source: str = "<array>") -> FaceLandmarks:
        image = as_rgb_uint8(image, source)
        mp_faces = self.mediapipe.mesh(image)
        if not mp_faces:
            result = self.dlib.detect(image, source)
            return FaceLandmarks(
                result.points, result.box, result.n_faces, self.name,
                result.notes + ("MediaPipe found no face: the lip points are dlib's",),
            )
        face = mp_faces[0]
        mp68 = ibug68_from_mesh(face.mesh)
        notes = list(_several(len(mp_faces)))
        boxes = self.dlib.landmarker.boxes(image)
        overlaps = [(_iou(box, face.box), box) for box, _ in boxes]
        best = max(overlaps, key=lambda o: o[0], default=(0.0, None))
        if best[1] is not None and best[0] >= 0.3:
            box = best[1]
        else:
            lo, hi = mp68.min(axis=0), mp68.max(axis=0)
            box = np.array([lo[0], mp68[19, 1], hi[0], hi[1]], dtype=np.float32)
            notes.append("dlib's HOG missed the face: its 68 points were placed in MediaPipe's box")
        lips = _corner_origin(face.mesh[MEDIAPIPE_LIPS20, :2])
        points = np.concatenate([self.dlib.landmarker.landmarks(image, box), lips])
        return FaceLandmarks(points, _corner_origin(face.box), len(mp_faces), self.name, tuple(notes))


DETECTORS = {"hybrid": HybridDetector, "dlib": DlibDetector, "mediapipe": MediaPipeDetector}
_instances: dict[str, LandmarkDetector] = {}


def get_detector(name: str = "hybrid") -> LandmarkDetector:
    """The shared detector instance of a backend name (models load once per process)."""
    if name not in DETECTORS:
        raise ValueError(f"landmark detector: expected one of {sorted(DETECTORS)}, got {name!r}")
    if name not in _instances:
        _instances[name] = DETECTORS[name]()
    return _instances[name]


def detect_landmarks(image: np.ndarray, detector: str | LandmarkDetector = "hybrid") -> np.ndarray:
    """The 88 hybrid landmarks (88, 2) float32 px of the largest face in an (H, W, 3) uint8 RGB
    image. Raises :class:`NoFaceError` when there is none. See :meth:`LandmarkDetector.detect`
    for the box, the face count and notes."""
    det = get_detector(detector) if isinstance(detector, str) else detector
    return det.detect(image).points
