"""Pluggable, offline landmark detectors producing the 88-point hybrid set.

* ``dlib``: HOG box + dlib's 68-point predictor; the 20 lip points are dlib's own mouth points.
  Non-commercial (iBUG 300-W training data).
* ``mediapipe``: BlazeFace + the 468-point face mesh (Apache-2.0) run with LiteRT; the 68 iBUG
  points come from the documented 468→68 table, the 20 lip points from the mesh. Licence-clean.
* ``hybrid`` (default, the paper's configuration): dlib's 68 + MediaPipe's 20 lip points; dlib's
  predictor runs in a box estimated from MediaPipe's face, HOG only when MediaPipe finds none.
* ``lids`` (``facegeo track``'s default): ``hybrid`` with the Face Landmarker's mesh (v2) and the
  eyes' 12 points (iBUG 36-47) taken from it: dlib's and the v1 mesh's lids barely close on a shut
  eye (lid gap over eye width 0.35 open, 0.20-0.25 shut on the ground-truth take of
  ``benchmarks/bench_track_truth.py``), v2's do (0.36 open, 0.07-0.13 shut) and tell a wink.
  Symmetric: the mesh and dlib's points are each the mean of those found on the face and, mapped
  back, on its mirror image.

Several faces: the largest is used and a note says so. No face: :class:`NoFaceError`.

Rotation search: dlib's predictor and MediaPipe's detector assume a roughly upright face; on a
photo turned by 90°, 180° or 270° they return landmarks that are wrong but fit well (an
upside-down face came out as an upright one). Every detector therefore first runs BlazeFace on
the photo turned by 0, 1, 2 and 3 quarter turns (:func:`upright_quarter_turns`, ~4 small
inferences), detects on the turn where the face scores best (if it beats the photo as it is by
:data:`ROTATION_MARGIN`), and maps the landmarks back to the photo's own pixels, with a note.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from facegeo.errors import NoFaceError
from facegeo.landmarks.dense import face_mesh_mirror
from facegeo.landmarks.dlib_detector import DlibLandmarker
from facegeo.landmarks.mediapipe_mesh import MEDIAPIPE_LIPS20, MediaPipeFace, MediaPipeFaceMesh, ibug68_from_mesh
from facegeo.photo import as_rgb_uint8
from facegeo.landmarks.scheme import EYES, IBUG_MIRROR, MOUTH

__all__ = [
    "FaceLandmarks",
    "LandmarkDetector",
    "DlibDetector",
    "MediaPipeDetector",
    "HybridDetector",
    "DETECTORS",
    "get_detector",
    "detect_landmarks",
    "upright_quarter_turns",
    "ROTATION_MARGIN",
    "DLIB_BOX_FROM_MEDIAPIPE",
    "dlib_box_from_mediapipe",
]

#: A quarter turn of the photo is used only when BlazeFace's best score on it exceeds the score
#: on the photo as it is by this much (astronaut: 0.92 upright; 0.86, 0.60, 0.77 turned by 90°,
#: 180°, 270°), so an upright face is never turned on noise.
ROTATION_MARGIN = 0.05
#: The rotation search runs on a copy whose longer side is at most this (BlazeFace's input is
#: 128², so this changes its scores by little and saves turning a large photo four times).
SEARCH_SIDE = 256


@dataclass(frozen=True)
class FaceLandmarks:
    """Landmarks of one face.

    points: (88, 2) float32, pixels (corner-origin convention of :mod:`facegeo.camera`).
    box: (4,) float32 face box x0, y0, x1, y1 in pixels (same convention).
    n_faces: how many faces the detector found (the largest is the one returned).
    detector: the backend's name. notes: remarks for the user (e.g. several faces).
    dense: (468, 2) float32 MediaPipe face-mesh points, pixels (same convention), or None when
    the backend ran no face mesh. dense_spread: (468,) float32 px, the mesh model's own spread of
    each point on this photo (:meth:`MediaPipeFaceMesh.spread`), or None.
    """

    points: np.ndarray
    box: np.ndarray
    n_faces: int
    detector: str
    notes: tuple[str, ...] = field(default=())
    dense: np.ndarray | None = None
    dense_spread: np.ndarray | None = None


@runtime_checkable
class LandmarkDetector(Protocol):
    """A detector: ``detect(image (H, W, 3) uint8 RGB, source) -> FaceLandmarks``."""

    name: str

    def detect(self, image: np.ndarray, source: str = "<array>") -> FaceLandmarks: ...


def _several(n: int) -> tuple[str, ...]:
    return (f"{n} faces found; the largest is used",) if n > 1 else ()


#: (ox, oy, kw, kh): dlib's HOG box for a face, from MediaPipe's 68-point estimate of it (see
#: :func:`dlib_box_from_mediapipe`). Fitted by ``benchmarks/calibrate_dlib_box.py``: least squares
#: on 151 samples from 18 photos where HOG finds the face (the real photos of
#: ``benchmarks/sample_photos.py`` and the head-scan renders, each scaled, turned, shifted and
#: mirrored). Leaving one photo out, the box's corners miss HOG's by 8 % of its side (median; HOG's
#: own scale steps are 20 %), and dlib's points move by 1.9 % of the inter-ocular distance
#: (median; scaling the photo or shifting it by 3-6 px moves today's HOG-box points by 1.8 %).
DLIB_BOX_FROM_MEDIAPIPE = (-0.0358, -0.2195, 2.9392, 2.9297)


def dlib_box_from_mediapipe(mp68: np.ndarray, constants: tuple[float, ...] | np.ndarray = DLIB_BOX_FROM_MEDIAPIPE) -> np.ndarray:
    """The box dlib's HOG detector would give the face of MediaPipe's 68 points ``mp68`` ((68, 2)
    px, pixel-centre convention): (4,) float32 x0, y0, x1, y1 px, same convention. With c the
    points' centroid and s their RMS distance from it, the box is centred at c + s·(ox, oy) and
    is s·kw wide and s·kh high (``constants`` = (ox, oy, kw, kh))."""
    points = np.asarray(mp68, dtype=np.float64)
    centre = points.mean(axis=0)
    radius = float(np.sqrt(((points - centre) ** 2).sum(axis=1).mean()))
    ox, oy, kw, kh = constants
    middle = centre + radius * np.array([ox, oy])
    half = radius * np.array([kw, kh]) / 2
    return np.concatenate([middle - half, middle + half]).astype(np.float32)


def _corner_origin(points: np.ndarray) -> np.ndarray:
    """dlib/MediaPipe/OpenCV pixel coordinates (pixel centres at integers) -> facegeo's
    corner-origin convention (pixel centres at +0.5), as float32."""
    return (np.asarray(points, dtype=np.float32) + 0.5).astype(np.float32)


def _no_face(source: str, detector: str) -> NoFaceError:
    return NoFaceError(source, f"face ({detector} detector)", "a photo showing one face", "no face")


def upright_quarter_turns(image: np.ndarray, mesh: MediaPipeFaceMesh | None = None) -> int:
    """k in 0..3 such that ``np.rot90(image, k)`` (k counter-clockwise quarter turns) shows the
    face most upright, judged by BlazeFace's best detection score; 0 unless a turn beats the
    photo as it is by :data:`ROTATION_MARGIN`."""
    mesh = mesh or get_detector("mediapipe").mesh
    scale = SEARCH_SIDE / max(image.shape[:2])
    if scale < 1.0:  # BlazeFace sees 128² anyway: turn a small copy, not the full photo
        size = (max(1, round(image.shape[1] * scale)), max(1, round(image.shape[0] * scale)))
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    scores = [max((d.score for d in mesh.detect(np.ascontiguousarray(np.rot90(image, k)))), default=0.0) for k in range(4)]
    best = int(np.argmax(scores))
    return best if scores[best] >= scores[0] + ROTATION_MARGIN else 0


def _turn_back(points: np.ndarray, k: int, turned_shape: tuple[int, ...]) -> np.ndarray:
    """Corner-origin (x, y) pixels in ``np.rot90(image, k)`` -> the same points in ``image``."""
    p = np.asarray(points, dtype=np.float32)
    height, width = turned_shape[:2]
    for _ in range(k):  # undo one counter-clockwise quarter turn: (x, y) -> (H - y, x)
        p = np.stack([height - p[:, 1], p[:, 0]], axis=1)
        height, width = width, height
    return p.astype(np.float32)


class _UprightSearch:
    """``detect`` = rotation search (module docstring) around the detector's ``_detect``."""

    name: str

    def _probe(self) -> MediaPipeFaceMesh:
        return get_detector("mediapipe").mesh

    def _detect(self, image: np.ndarray, source: str) -> FaceLandmarks:
        raise NotImplementedError

    def detect(self, image: np.ndarray, source: str = "<array>") -> FaceLandmarks:
        """The 88 landmarks of the largest face in an (H, W, 3) uint8 RGB image (corner-origin
        pixels of ``image``); raises :class:`NoFaceError` when there is none."""
        image = as_rgb_uint8(image, source)
        k = upright_quarter_turns(image, self._probe())
        if k == 0:
            return self._detect(image, source)
        turned = np.ascontiguousarray(np.rot90(image, k))
        found = self._detect(turned, source)
        corners = _turn_back(found.box.reshape(2, 2), k, turned.shape)
        box = np.concatenate([corners.min(axis=0), corners.max(axis=0)]).astype(np.float32)
        turn = {1: "90° counter-clockwise", 2: "180°", 3: "90° clockwise"}[k]
        note = f"the face is upright with the photo turned {turn}: landmarks found there and mapped back"
        dense = None if found.dense is None else _turn_back(found.dense, k, turned.shape)
        return FaceLandmarks(_turn_back(found.points, k, turned.shape), box, found.n_faces, found.detector, found.notes + (note,),
                             dense, found.dense_spread)


class DlibDetector(_UprightSearch):
    """dlib 68 points; the lip points repeat dlib's mouth points 48..67."""

    name = "dlib"

    def __init__(self, landmarker: DlibLandmarker | None = None):
        self.landmarker = landmarker or DlibLandmarker()

    def _detect(self, image: np.ndarray, source: str) -> FaceLandmarks:
        faces = self.landmarker(image)
        if not faces:
            raise _no_face(source, self.name)
        face = faces[0]
        points = np.concatenate([face.points, face.points[MOUTH]]).astype(np.float32)
        return FaceLandmarks(points, _corner_origin(face.box), len(faces), self.name, _several(len(faces)))


class MediaPipeDetector(_UprightSearch):
    """MediaPipe face mesh: 468→68 table + 20 lip points (licence-clean)."""

    name = "mediapipe"

    def __init__(self, mesh: MediaPipeFaceMesh | None = None):
        self.mesh = mesh or MediaPipeFaceMesh()

    def _probe(self) -> MediaPipeFaceMesh:
        return self.mesh

    def _detect(self, image: np.ndarray, source: str) -> FaceLandmarks:
        faces = self.mesh(image)
        if not faces:
            raise _no_face(source, self.name)
        face = faces[0]
        points = np.concatenate([ibug68_from_mesh(face.mesh), face.mesh[MEDIAPIPE_LIPS20, :2]])
        return FaceLandmarks(_corner_origin(points), _corner_origin(face.box), len(faces), self.name, _several(len(faces)),
                             _corner_origin(face.mesh[:, :2]), self.mesh.spread(image, face, face_mesh_mirror()))


class HybridDetector(_UprightSearch):
    """The paper's 88 points: dlib's 68 + MediaPipe's 20 lip points.

    The face is MediaPipe's largest; dlib's predictor runs in the box dlib's HOG detector would
    give it, estimated from MediaPipe's 68 points (:func:`dlib_box_from_mediapipe`), so HOG
    (0.34 s to load, 0.12 s per 512² photo) is not run. If MediaPipe finds nothing, dlib alone
    (HOG + predictor) is used, with a note.
    """

    name = "hybrid"

    def __init__(self, dlib: DlibDetector | None = None, mediapipe: MediaPipeDetector | None = None, eyes: str = "dlib",
                 name: str = "hybrid", symmetric: bool = False):
        """``eyes``: where the eyes' 12 points (iBUG 36-47) come from, ``"dlib"`` or ``"mesh"`` (the
        face mesh's, by :func:`~facegeo.landmarks.mediapipe_mesh.ibug68_from_mesh`; dlib's where
        MediaPipe finds no face). ``name``: the detector's name in its results. ``symmetric``:
        every point the mean of the face's and its mirror image's (:meth:`_landmarks`)."""
        if eyes not in ("dlib", "mesh"):
            raise ValueError(f"eyes: expected 'dlib' or 'mesh', got {eyes!r}")
        self.dlib = dlib or DlibDetector()
        self.mediapipe = mediapipe or MediaPipeDetector()
        self.eyes, self.name, self.symmetric = eyes, name, symmetric

    def _probe(self) -> MediaPipeFaceMesh:
        return self.mediapipe.mesh

    def _detect(self, image: np.ndarray, source: str) -> FaceLandmarks:
        mesh = self.mediapipe.mesh
        mp_faces = mesh(image)
        if not mp_faces:  # the short-range detector misses faces under ~60 px that HOG finds: the mesh on HOG's face
            result = self.dlib._detect(image, source)
            face = mesh.face_from_points(image, result.points[:68] - 0.5)
            if face.presence >= mesh.min_presence:
                found = self._landmarks(image, face, result.n_faces)
                return dataclasses.replace(found, notes=found.notes + ("MediaPipe's detector found no face: the face mesh "
                                                                       "was placed on dlib's",))
            return FaceLandmarks(
                result.points, result.box, result.n_faces, self.name,
                result.notes + ("MediaPipe found no face: the lip points are dlib's",),
            )
        return self._landmarks(image, mp_faces[0], len(mp_faces))

    def _landmarks(self, image: np.ndarray, face: MediaPipeFace, n_faces: int, spread: np.ndarray | None = None,
                   mirrored: np.ndarray | None = None) -> FaceLandmarks:
        """The 88 points of MediaPipe's ``face`` in ``image``: dlib's predictor in the box HOG would
        give it, the mesh's lips (and eyes, with ``eyes="mesh"``), its dense points and their
        spread (``spread`` (468,) px where given, else the mesh model's on this image). With
        ``symmetric``, each is the mean of the points found on the crop and, mirrored back, on its
        mirror image (``mirrored``, the mesh's, where that pass was made already; the spread then
        always this image's)."""
        mesh = self.mediapipe.mesh
        if self.symmetric:
            if mirrored is None:
                mirrored = mesh.mirrored_mesh(image, face, face_mesh_mirror())[0]
            spread = mesh.spread(image, face, face_mesh_mirror(), mirrored)
            face = dataclasses.replace(face, mesh=((face.mesh + mirrored) / 2).astype(np.float32))
        ibug = ibug68_from_mesh(face.mesh)
        box = dlib_box_from_mediapipe(ibug)
        lips = _corner_origin(face.mesh[MEDIAPIPE_LIPS20, :2])
        dlib68 = self.dlib.landmarker.landmarks(image, box)
        if self.symmetric:  # dlib on the mirror image in the mirrored box, mapped back and renumbered
            width = image.shape[1]
            flipped = self.dlib.landmarker.landmarks(image, np.array([width - 1 - box[2], box[1], width - 1 - box[0], box[3]]),
                                                     mirror=True)
            flipped[:, 0] = width - flipped[:, 0]  # corner-origin x
            dlib68 = ((dlib68 + flipped[IBUG_MIRROR]) / 2).astype(np.float32)
        points = np.concatenate([dlib68, lips])
        if self.eyes == "mesh":
            points[EYES] = _corner_origin(ibug[EYES])
        return FaceLandmarks(points, _corner_origin(face.box), n_faces, self.name, _several(n_faces),
                             _corner_origin(face.mesh[:, :2]), mesh.spread(image, face, face_mesh_mirror()) if spread is None else spread)

    def follow(self, image: np.ndarray, previous: FaceLandmarks, source: str = "<array>",
               keep_spread: bool = False) -> FaceLandmarks | None:
        """The face of ``previous`` (this detector's result on the previous frame of a video) in
        ``image`` (H, W, 3) uint8 RGB, without the face detector or the rotation search: the mesh
        on the ROI of the previous frame's mesh (:meth:`MediaPipeFaceMesh.follow`). None where the
        face is lost (detect it again with :meth:`detect`) or ``previous`` has no mesh.
        ``keep_spread``: the dense points keep ``previous``'s spread (where it has one) instead of
        the mesh model's mirror pass on this frame. A symmetric detector makes that pass anyway and
        judges whether the face is lost by the mean of the two passes' presence."""
        if previous.dense is None:
            return None
        image, mesh = as_rgb_uint8(image, source), self.mediapipe.mesh
        if not self.symmetric:
            face = mesh.follow(image, np.asarray(previous.dense, np.float64) - 0.5)
            return None if face is None else self._landmarks(image, face, 1, previous.dense_spread if keep_spread else None)
        # the face's presence, too, is the mean of the crop's and its mirror image's
        face = mesh.follow(image, np.asarray(previous.dense, np.float64) - 0.5, min_presence=0.0)
        mirrored, presence = mesh.mirrored_mesh(image, face, face_mesh_mirror())
        if (face.presence + presence) / 2 < mesh.min_presence:
            return None
        return self._landmarks(image, face, 1, mirrored=mirrored)


def lids_detector() -> HybridDetector:
    """The ``lids`` detector (module docstring): the hybrid one with the Face Landmarker's mesh
    (v2) and its eyes, every point the mean of the face's and its mirror image's (``symmetric``:
    a clip and its mirror image then give mirrored points, and each detector's own left-right
    bias averages out), the mesh model on one thread (a clip is observed by two processes at once:
    two threads each took 7.1 ms a pass against 5.9 ms with one; measured in benchmarks/RESULTS.md,
    "symmetric landmarks")."""
    return HybridDetector(mediapipe=MediaPipeDetector(MediaPipeFaceMesh(mesh_model="v2", num_threads=1)), eyes="mesh", name="lids",
                          symmetric=True)


DETECTORS = {"hybrid": HybridDetector, "dlib": DlibDetector, "mediapipe": MediaPipeDetector, "lids": lids_detector}
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
