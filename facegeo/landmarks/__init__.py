"""The 88-point hybrid landmarks: detectors (dlib, MediaPipe, hybrid), the scheme and the loss."""

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
