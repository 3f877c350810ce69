"""Checks that keep a wrong fit from being reported as a result.

Two entry points, each called by one line of :mod:`facegeo.fitting`:

* :func:`check_landmarks` (before :func:`~facegeo.fitting.fit_landmarks` fits): the points must
  be pixel coordinates of a face in the camera's image. Refused: points farther than one image
  size outside the image (:data:`MAX_OUTSIDE_IMAGE`: 1e15 px fitted to "a face" 1e12 mm behind
  the camera), and points that do not spread over a face: RMS distance of the 51 non-jaw iBUG
  points to their centre below :data:`MIN_SPREAD_PX` (all at one pixel made solvePnP fail
  inside OpenCV), or the ratio of the short to the long axis of their spread below
  :data:`MIN_ASPECT` (all on one line). A frontal face has an aspect of about 0.8 and a full
  profile still above 0.3.
* :func:`check_fit` (at the end of :func:`~facegeo.fitting.fit`): the result must be finite, the
  face in front of the camera (every landmark vertex at z < 0, camera space looking down −Z),
  the detected landmarks followed by the fit (:func:`landmark_error_percent` at most
  :data:`MAX_LANDMARK_ERROR_PERCENT`), and, for a photo with an alpha channel, the face mostly
  opaque (mean alpha ≥ :data:`MIN_FACE_OPACITY` inside the fitted landmarks' outline).

What the landmark bar measures (issue 47). A wrong fit is one made to landmarks that are not a
face the model can take: a detection on a face lying on its side, in a wrong box, on something
else. Such landmarks are missed by the fit *everywhere*, by a good part of the face's size; a
right fit to a small, turned or half-hidden face misses *a few* points by a lot (dlib's lower lip
on the cameraman's profile, 15–17 % of his inter-ocular distance; the far brow of a face turned
40°), because the detector places those few badly. So the bar reads:

* the 51 inner iBUG points (:data:`~facegeo.landmarks.scheme.INNER_FACE`: brows, nose, eyes,
  mouth), which every detector gives and every fit uses; not the jaw (it slides, and with dense
  landmarks it is left out), not MediaPipe's lip points beside dlib's mouth, not the dense points;
* the RMS of the best-followed :data:`FOLLOWED_SHARE` of them (41 of 51), so that up to ten
  misplaced points do not refuse a right fit, while a wrong detection, missed everywhere,
  cannot hide in ten;
* in % of the face's *frontal* inter-ocular distance (:func:`frontal_inter_ocular_distance`:
  the fitted face's outer-eye-corner distance, mm, seen at its depth, f · IOD / depth), which
  does not shrink as the face turns away, as the detected distance does (a face turned 40° has
  0.75 of it, one turned 60° half).

Measured (``benchmarks/bench_fit_checks.py``), in % of the frontal distance: the real photos
of ``benchmarks/sample_photos.py`` 1.8–3.5 (Walter White turned 38°: 3.5) and the cameraman (a
small face turned about 60°, half behind a camera) 5.7, 6.9–7.8 downscaled; every photo shrunk to
14 px between the eyes ≤ 4.5 (the cameraman 7.1); with dlib or MediaPipe alone ≤ 2.5; renders of
two real head scans 1.7–4.5 up to yaw ±60° and pitch ±15°, 5.3–6.8 at ±75°. Wrong fits: the
photos turned by 90° or 270° and detected there without the rotation search
(:mod:`facegeo.landmarks.detectors`) ≥ 30; dlib's points in the face's box shifted by 0.4 of its
size ≥ 27, in a box half its size ≥ 12; in one 1.8 times its size ≥ 14.5 but for two photos (5.4,
5.9) whose points there are still a face's; the inner points shuffled ≥ 55. The bar, 10 %, sits
1.3× above the worst right fit and 2.7× below the clear wrong ones. The bar before issue 47 (the
landmark RMS over all the points the fit used, > 6 % of the detected inter-ocular distance, which
grows as 1/cos(yaw) with the turn) refused the cameraman (10 %), a scan render turned 60° (6.3,
7.7 %) and Walter White shrunk to 40 px between the eyes (6.4 %).

Not caught by any landmark bar: a detection that is wrong but self-consistent, such as the
face-shaped points the detectors find on an upside-down face (the bundled photo turned 180°
without the rotation search: 4.7 %; of four photos that gave such points one exceeds the bar,
11.7 %); the rotation search is what prevents those. Points squashed or stretched as a whole
are a face the model can take (turned, or wider): they pass too.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from facegeo.camera import Camera, euler_from_rotation
from facegeo.errors import InputError, NoFaceError, check_finite
from facegeo.landmarks.scheme import IBUG68, INNER_FACE, N_LANDMARKS, OUTER_EYE_CORNERS, inter_ocular_distance

if TYPE_CHECKING:
    from facegeo.fitting.result import Fit

__all__ = ["check_landmarks", "check_fit", "landmark_error_percent", "frontal_inter_ocular_distance", "MAX_OUTSIDE_IMAGE",
           "MIN_SPREAD_PX", "MIN_ASPECT", "MAX_LANDMARK_ERROR_PERCENT", "FOLLOWED_SHARE", "MIN_FACE_OPACITY"]

#: Landmarks may lie outside the image (a face cut by the border) by at most this many image
#: widths (x) or heights (y).
MAX_OUTSIDE_IMAGE = 1.0
#: Least RMS distance (px) of the non-jaw iBUG points to their centre.
MIN_SPREAD_PX = 2.0
#: Least ratio of the short to the long principal axis of the non-jaw iBUG points.
MIN_ASPECT = 0.1
#: Largest :func:`landmark_error_percent` of a fit that is reported: the RMS of the best-followed
#: :data:`FOLLOWED_SHARE` of the 51 inner points in % of the face's frontal inter-ocular distance
#: (right fits ≤ 7.8, wrong detections ≥ 12 and most ≥ 27: module docstring).
MAX_LANDMARK_ERROR_PERCENT = 10.0
#: The share of the 51 inner points, the best followed, whose RMS the bar reads.
FOLLOWED_SHARE = 0.8
#: Least mean alpha inside the fitted face outline of a photo with an alpha channel.
MIN_FACE_OPACITY = 0.5

_SOURCE = "<landmarks>"


def check_landmarks(targets: np.ndarray, camera: Camera) -> None:
    """Refuse landmarks that cannot be a face in ``camera``'s image (module docstring).

    Args:
        targets: (88, 2) float pixels, corner-origin; NaN rows are missing points.
        camera: the intrinsics of the image (its width and height bound the coordinates).
    Raises:
        InputError: naming ``landmarks`` and what was expected.
    """
    targets = np.asarray(targets, dtype=np.float64)
    if targets.shape != (N_LANDMARKS, 2):
        raise InputError(_SOURCE, "landmarks", f"shape ({N_LANDMARKS}, 2) in pixels", str(targets.shape))
    valid = np.isfinite(targets).all(axis=1)
    size = np.array([camera.width, camera.height], dtype=np.float64)
    lo, hi = -MAX_OUTSIDE_IMAGE * size, (1.0 + MAX_OUTSIDE_IMAGE) * size
    outside = valid & np.any((targets < lo) | (targets > hi), axis=1)
    if outside.any():
        x, y = targets[np.flatnonzero(outside)[0]]
        raise InputError(_SOURCE, "landmarks", f"pixel coordinates within {MAX_OUTSIDE_IMAGE:g} image size of the "
                         f"{camera.width}x{camera.height} image", f"a point at ({x:.4g}, {y:.4g}) px")
    inner = targets[INNER_FACE][valid[INNER_FACE]]
    if len(inner) < 3:
        return  # fit_landmarks refuses fewer than 6 points itself
    centred = inner - inner.mean(axis=0)
    spread = float(np.sqrt((centred**2).sum(axis=1).mean()))
    if spread < MIN_SPREAD_PX:
        raise InputError(_SOURCE, "landmarks", f"points spread over a face (RMS ≥ {MIN_SPREAD_PX:g} px around their centre)",
                         f"{spread:.3g} px")
    axes = np.sqrt(np.maximum(np.linalg.eigvalsh(centred.T @ centred / len(inner)), 0.0))
    if axes[0] < MIN_ASPECT * axes[1]:
        raise InputError(_SOURCE, "landmarks", f"points spread over a face (short/long axis ≥ {MIN_ASPECT:g})",
                         f"points on a line (ratio {axes[0] / axes[1]:.3g})")


def check_fit(result: Fit, image: Any) -> None:
    """Refuse a fit that must not be reported (module docstring).

    Args:
        result: the fit, before it is returned.
        image: what :func:`~facegeo.fitting.fit` was given (a Photo with ``opacity`` is checked
            for a transparent face; arrays and paths are not).
    Raises:
        InputError: non-finite values, or a face behind the camera.
        NoFaceError: landmarks the model cannot follow (a wrong detection: one line with the
            measure, the face's size and turn, and what to give instead), or a transparent face.
    """
    source = str(result.info.get("source", "<array>"))
    names = ("vertices", "rotation", "translation", "alpha", "delta", "beta", "gamma", "landmarks_fitted")
    check_finite({f"fit {name}": getattr(result, name) for name in names}, source)
    depth = result.vertices[result.landmark_vertices, 2]
    if not np.all(depth < 0):
        raise InputError(source, "pose", "a face in front of the camera (z < 0 mm)",
                         f"landmark vertices at z up to {float(depth.max()):.4g} mm")
    percent = landmark_error_percent(result)
    if not percent <= MAX_LANDMARK_ERROR_PERCENT:
        raise NoFaceError(source, "landmarks", _expected_landmarks(), _found_landmarks(result, percent))
    opacity = getattr(image, "opacity", None)
    if opacity is not None:
        outline = cv2.convexHull(np.round(result.landmarks_fitted[IBUG68] - 0.5).astype(np.int32))
        mask = np.zeros(opacity.shape, np.uint8)
        cv2.fillConvexPoly(mask, outline, 1)
        inside = opacity[mask.astype(bool)]
        mean = float(inside.mean()) if inside.size else 0.0
        if mean < MIN_FACE_OPACITY:
            raise NoFaceError(source, "alpha channel", f"an opaque face (mean alpha ≥ {MIN_FACE_OPACITY:g} inside it)",
                              f"a face {100 * (1 - mean):.0f} % transparent")


def frontal_inter_ocular_distance(result: Fit) -> float:
    """The face's inter-ocular distance (px) as the camera would see it facing it at its depth:
    focal × the fitted face's outer-eye-corner distance (mm) / the depth of their midpoint (mm).
    Unlike the detected distance it does not shrink as the face turns. 0 for a face not in
    front of the camera."""
    eyes = np.asarray(result.vertices, dtype=np.float64)[np.asarray(result.landmark_vertices)[OUTER_EYE_CORNERS]]
    depth = -float(eyes[:, 2].mean())
    if not depth > 0:
        return 0.0
    return float(result.camera.focal) * float(np.linalg.norm(eyes[0] - eyes[1])) / depth


def landmark_error_percent(result: Fit) -> float:
    """How far the fit misses the detected landmarks (module docstring): the RMS distance (px)
    of the best-followed :data:`FOLLOWED_SHARE` of the 51 inner iBUG points (those with finite
    errors), in % of :func:`frontal_inter_ocular_distance`; inf when fewer than 6 inner points
    were detected or the face has no size."""
    errors = np.asarray(result.landmark_errors_px, dtype=np.float64)[INNER_FACE]
    errors = np.sort(errors[np.isfinite(errors)])
    size = frontal_inter_ocular_distance(result)
    if len(errors) < 6 or not size > 0:
        return float("inf")
    kept = errors[: int(np.ceil(FOLLOWED_SHARE * len(errors)))]
    return 100.0 * float(np.sqrt(np.mean(kept**2))) / size


def _expected_landmarks() -> str:
    return (f"landmarks the face model can follow (RMS of the best-followed {100 * FOLLOWED_SHARE:.0f} % of the 51 inner "
            f"points ≤ {MAX_LANDMARK_ERROR_PERCENT:g} % of the face's inter-ocular distance)")


def _found_landmarks(result: Fit, percent: float) -> str:
    """What was found and what to do, on one line: the measure, the face's size and fitted turn,
    the usual causes and what to give instead (another detector where one is named)."""
    iod = inter_ocular_distance(result.landmarks)
    yaw = euler_from_rotation(result.rotation)[0]
    other = ", or try --landmarks mediapipe" if result.info.get("detector") in ("hybrid", "dlib") else ""
    return (f"{percent:.3g} % on a face {iod:.0f} px between the eyes, fitted as turned {abs(yaw):.0f}°: a wrong detection "
            "(not a face, or a face on its side, mostly hidden or near profile); give a photo of one upright, unhidden face "
            f"turned less than about 60° from the camera{other}")
