"""The focal length of a photo whose lens is unknown, from the face in it.

A photo's focal length cannot be told from its pixels alone, and the usual guess, a fixed field
of view, fails on the photos users bring: a portrait cropped tight to the face "seen" through a
40° field of view puts the head a few decimetres from the lens, and a fit under that strong
perspective widens the face and shrinks the nose (issue 25: a 135 mm portrait from 1.7 m was
fitted at 430 mm). What is known is the size of a face: the focal is set so the face stands
:data:`ASSUMED_SUBJECT_DISTANCE_MM` from the camera, f = d · iod_px / iod_mm, with iod_mm the
model's mean outer-eye-corner distance and iod_px the detected one (a crop changes the focal
with the face, and a slim face stays slim at any crop). The distance was chosen on renders of
real head scans with 50 mm and 135 mm lenses and a tight crop (benchmarks/RESULTS.md).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from facegeo.camera import Camera
from facegeo.landmarks.scheme import inter_ocular_distance
from facegeo.morphable_model import MorphableModel

__all__ = ["ASSUMED_SUBJECT_DISTANCE_MM", "camera_for_face"]

#: Distance (mm) from the camera at which a face of unknown lens is assumed to stand.
ASSUMED_SUBJECT_DISTANCE_MM = 1000.0


def camera_for_face(camera: Camera, landmarks: np.ndarray, model: MorphableModel,
                    distance_mm: float = ASSUMED_SUBJECT_DISTANCE_MM) -> tuple[Camera, str | None]:
    """``camera`` itself if its focal is known, else a copy whose focal puts the face
    ``distance_mm`` away (principal point kept).

    Args:
        camera: the photo's camera (``focal_known`` False: the focal is a placeholder).
        landmarks: (88, 2) detected landmarks, pixels.
        model: the morphable model (its mean outer-eye-corner distance, mm).
        distance_mm: the assumed subject distance.
    Returns:
        (camera, note): the note says what was assumed (None when the focal was known).
    """
    if camera.focal_known:
        return camera, None
    iod_px = inter_ocular_distance(landmarks)
    iod_mm = inter_ocular_distance(model.mean_shape[model.landmark_indices])
    if not (np.isfinite(iod_px) and iod_px > 1.0):
        return camera, "focal length unknown and the eyes not found: 40° field of view assumed"
    focal = distance_mm * iod_px / iod_mm
    note = (f"focal length unknown: set to {focal:.0f} px so the face stands {distance_mm / 1000:.1f} m from the camera "
            "(give --focal for a known lens)")
    return dataclasses.replace(camera, focal=focal), note
