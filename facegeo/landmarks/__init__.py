"""The 88-point hybrid landmarks: detectors (dlib, MediaPipe, hybrid), the scheme and the loss;
MediaPipe's 468 points on the model's surface (:mod:`facegeo.landmarks.dense`)."""

from facegeo.landmarks.dense import (
    DenseCorrespondence,
    load_dense_correspondence,
    points_on_mesh,
    points_on_mesh_torch,
)
from facegeo.landmarks.detectors import (
    DETECTORS,
    DlibDetector,
    FaceLandmarks,
    HybridDetector,
    LandmarkDetector,
    MediaPipeDetector,
    detect_landmarks,
    get_detector,
)
from facegeo.landmarks.scheme import HYBRID_MIRROR, LANDMARK_WEIGHTS, N_LANDMARKS, landmark_loss

__all__ = [
    "DenseCorrespondence",
    "load_dense_correspondence",
    "points_on_mesh",
    "points_on_mesh_torch",
    "DETECTORS",
    "DlibDetector",
    "FaceLandmarks",
    "HybridDetector",
    "LandmarkDetector",
    "MediaPipeDetector",
    "detect_landmarks",
    "get_detector",
    "HYBRID_MIRROR",
    "LANDMARK_WEIGHTS",
    "N_LANDMARKS",
    "landmark_loss",
]
