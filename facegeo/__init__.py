"""facegeo: one photo of a face in, a measured, relightable 3D face asset out.

The geometry half: the morphable model, camera and SH lighting, the 88-point hybrid landmarks and
the analysis-by-synthesis fit. Public names are imported lazily so ``facegeo --help`` starts fast.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from facegeo.lazy_exports import lazy_exports

__version__ = "0.1.0"

_EXPORTS = {
    "MorphableModel": "facegeo.morphable_model",
    "load_model": "facegeo.model_files",
    "Camera": "facegeo.camera",
    "project": "facegeo.camera",
    "detect_landmarks": "facegeo.landmarks.detectors",
    "FaceLandmarks": "facegeo.landmarks.detectors",
    "LandmarkDetector": "facegeo.landmarks.detectors",
    "Fit": "facegeo.fitting",
    "Fitter": "facegeo.fitting",
    "fit": "facegeo.fitting",
    "fit_landmarks": "facegeo.fitting",
    "reconstruct": "facegeo.pipeline",
    "Asset": "facegeo.asset",
    "Photo": "facegeo.photo",
    "load_photo": "facegeo.photo",
    "FacegeoError": "facegeo.errors",
    "InputError": "facegeo.errors",
    "ModelFileError": "facegeo.errors",
    "NoFaceError": "facegeo.errors",
    "OutputError": "facegeo.errors",
}

__all__ = ["__version__", *_EXPORTS]

if TYPE_CHECKING:
    from facegeo.camera import Camera, project
    from facegeo.errors import FacegeoError, InputError, ModelFileError, NoFaceError, OutputError
    from facegeo.fitting import Fit, Fitter, fit, fit_landmarks
    from facegeo.landmarks.detectors import FaceLandmarks, LandmarkDetector, detect_landmarks
    from facegeo.model_files import load_model
    from facegeo.morphable_model import MorphableModel
    from facegeo.asset import Asset
    from facegeo.photo import Photo, load_photo
    from facegeo.pipeline import reconstruct


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
