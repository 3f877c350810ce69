"""How shut each eye is, read from the lids: the eyeBlink weights a tracker holds instead of fitting.

A face mesh's lid points barely part the fit's eyeBlink from the other shapes that move the lids
(squint, wide, a lowered brow, the gaze): on the ground-truth take of
``benchmarks/bench_track_truth.py`` the per-frame fit on the Face Landmarker's lids read a full
blink as 0.3 and a wink as 0.3 of one eye. MediaPipe's iris model (:mod:`facegeo.landmarks.iris`)
looks at one eye at a time, in a 64 × 64 crop, and its eye contour follows a shut lid: on that
take a wink's shut eye reads 0.11-0.16 of the eye's width between the lids where the open one
reads 0.35-0.39, and a blink 0.09-0.18.

The blink of an eye is read from three quantities:

* ``gap``: the lid gap in the photo, px: the mean distance across the eye's axis (the line
  through its corners) of the iris model's middle three upper-lid points from the lower-lid
  points facing them (:func:`lid_gaps`);
* ``open``: the gap this eye shows open, px, in this frame's pose: the model's neutral lid gap
  (the 88-point scheme's lid vertices, :func:`model_lid_gaps`) times the clip's ratio of the
  reader's gap to the model's (:func:`open_ratio`, the median over frames where the eyes are
  open; it absorbs where the reader puts a lid against where the scheme does, and the person's
  eyes against the model's). The model's gap follows the head's pitch, yaw and distance;
* ``SHUT_FRACTION``: the share of the open gap the reader still reads on a shut eye (the lashes'
  thickness at the crop's resolution; 0.24-0.51 on the take's shut frames);
* ``OPEN_NOISE``: how much narrower than ``open`` the reader reads an open eye by its noise
  alone (as a share of the open gap), which counts as open.

blink = clip(((open − gap) / open − OPEN_NOISE) / (1 − SHUT_FRACTION − OPEN_NOISE), 0, 1).

An eye turned away from the camera (the far eye of a turned head) is read worse than a near one
(on the take the far eye at 35° of yaw read 0.4-0.6 shut while open), so it takes the near eye's
reading as it turns away (:func:`blinks`): by the cosine between its outward direction
(:data:`EYE_OUTWARD_DEG` from the face's forward axis) and the direction to the camera, all its
own at :data:`FACING` [1] and above, all the near eye's at :data:`FACING` [0] and below. A wink on
a head turned further than that is read as a blink.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from facegeo.camera import Camera, project
from facegeo.landmarks.iris import EYE_CORNERS, LOWER_LID, UPPER_LID, IrisDetector

if TYPE_CHECKING:
    from facegeo.morphable_model import MorphableModel

__all__ = ["lid_gaps", "model_lid_gaps", "open_ratio", "blinks", "BLINK_NAMES", "SHUT_FRACTION", "OPEN_NOISE", "EYE_OUTWARD_DEG",
           "FACING", "LID_POINTS"]

#: The model's expressions that :func:`blinks` reads, subject's right eye then left (ICT-FaceKit's).
BLINK_NAMES = ("eyeBlink_R", "eyeBlink_L")
#: The share of the open gap the iris model reads between the lids of a shut eye.
SHUT_FRACTION = 0.4
#: The share of the open gap by which the reader reads an open eye narrower through its noise
#: alone: on the take's open eyes (--no-smooth, benchmarks/RESULTS.md "an open eye's noise") the
#: blink read without it has its 84th percentile at 0.05 frontally and 0.08 at ±35° of yaw,
#: i.e. a narrowing of 0.03-0.05 (blink × (1 − SHUT_FRACTION)); 0.06 leaves that noise at 0 and a
#: shut eye at 1.
OPEN_NOISE = 0.06
#: Each eye's outward direction: the face's forward axis turned this many degrees to its side.
EYE_OUTWARD_DEG = 20.0
#: Cosines of an eye's outward direction with the direction to the camera between which its own
#: reading gives way to the other eye's (all the other's at the first, all its own at the second).
FACING = (0.6, 0.85)
#: The 88-point scheme's lid points (iBUG 37, 38, 40, 41, 43, 44, 46, 47): the upper ones, then
#: the lower ones facing them, of the right eye then the left.
LID_POINTS = ((37, 38, 41, 40), (43, 44, 47, 46))
#: The iris model's lid rows whose gaps are averaged: the middle three of each lid, facing.
_GAP_ROWS = tuple((UPPER_LID[k], LOWER_LID[k]) for k in (3, 4, 5))


def _across(upper: np.ndarray, lower: np.ndarray, start: np.ndarray, end: np.ndarray) -> float:
    """Mean distance (px) of ``upper`` (K, 2) from ``lower`` (K, 2) across the line ``start`` → ``end``."""
    axis = np.asarray(end, np.float64) - np.asarray(start, np.float64)
    normal = np.array([-axis[1], axis[0]]) / max(float(np.linalg.norm(axis)), 1e-9)
    return float(np.abs((np.asarray(upper, np.float64) - np.asarray(lower, np.float64)) @ normal).mean())


def lid_gaps(image: np.ndarray, landmarks: np.ndarray, detector: IrisDetector | None = None) -> np.ndarray:
    """(2,) float64 px: the lid gap of the subject's right and left eye in ``image`` (H, W, 3)
    uint8 RGB (module docstring), the eyes found by the corners of ``landmarks`` (88, 2) px (iBUG
    36/39 and 42/45). NaN for an eye whose corners are not finite or less than 4 px apart."""
    detector = IrisDetector() if detector is None else detector
    rows = np.array(_GAP_ROWS)
    seen = detector.eyes(image, np.asarray(landmarks, np.float64))
    out = np.full(2, np.nan)
    for k, eye in enumerate(EYE_CORNERS):  # the subject's right eye, then the left
        if eye in seen:
            contour = seen[eye][1]
            out[k] = _across(contour[rows[:, 0]], contour[rows[:, 1]], contour[LOWER_LID[0]], contour[LOWER_LID[-1]])
    return out


def model_lid_gaps(model: MorphableModel, alpha: np.ndarray, delta: np.ndarray, rotation: np.ndarray,
                   translation: np.ndarray, camera: Camera) -> np.ndarray:
    """(2,) float64 px: the model's lid gap of the right and left eye (the scheme's
    :data:`LID_POINTS` across the line through the eye's corners, each pair's distance averaged)
    for identity ``alpha`` (n_id,) and expression ``delta`` (n_exp,), posed by ``rotation`` (3, 3)
    and ``translation`` (3,) mm and seen by ``camera``."""
    vertices = np.asarray(model.landmark_indices)[np.array([[36, 39, *LID_POINTS[0]], [42, 45, *LID_POINTS[1]]]).ravel()]
    shape = model.shape_numpy(alpha, delta, vertex_indices=vertices).astype(np.float64)  # corners, 2 upper, 2 lower per eye
    uv = project(shape, np.asarray(rotation, np.float64), np.asarray(translation, np.float64), camera).reshape(2, 6, 2)
    return np.array([_across(e[2:4], e[4:6], e[0], e[1]) for e in uv])


def open_ratio(gaps: np.ndarray, model_gaps: np.ndarray) -> np.ndarray:
    """(2,) float64: the clip's ratio of the reader's open lid gap to the model's neutral one, per
    eye: the median over frames of ``gaps`` / ``model_gaps`` (both (N, 2) px; NaN rows and
    frames are skipped). A clip's eyes are open most of the time, and a median ignores blinks in
    fewer than half of the frames. NaN for an eye with no frame."""
    ratio = np.asarray(gaps, np.float64) / np.asarray(model_gaps, np.float64)
    ratio[~np.isfinite(ratio) | (ratio <= 0)] = np.nan
    out = np.full(2, np.nan)
    for k in range(2):
        seen = ratio[:, k][np.isfinite(ratio[:, k])]
        if len(seen):
            out[k] = float(np.median(seen))
    return out


def blinks(gaps: np.ndarray, open_gaps: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(2,) float64 in [0, 1]: the blink of the right and left eye (module docstring) from their
    lid ``gaps`` (2,) px and the gaps they show open in this pose, ``open_gaps`` (2,) px, for a
    head posed by ``rotation`` (3, 3, model to camera; the camera looks along its −Z). An eye
    without a reading (NaN) takes the other's; NaN for both when neither has one."""
    value = np.clip(((open_gaps - gaps) / open_gaps - OPEN_NOISE) / (1.0 - SHUT_FRACTION - OPEN_NOISE), 0.0, 1.0)
    turn = np.radians(EYE_OUTWARD_DEG)
    outward = np.array([[-np.sin(turn), 0.0, np.cos(turn)], [np.sin(turn), 0.0, np.cos(turn)]])  # right eye at −x
    facing = (outward @ np.asarray(rotation, np.float64).T)[:, 2]
    own = np.clip((facing - FACING[0]) / (FACING[1] - FACING[0]), 0.0, 1.0)
    own[~np.isfinite(value)] = 0.0
    if not np.isfinite(value).any():
        return np.full(2, np.nan)
    filled = np.where(np.isfinite(value), value, value[::-1])
    far = int(np.argmin(own))
    out = filled.copy()
    out[far] = own[far] * filled[far] + (1.0 - own[far]) * filled[1 - far]
    return out
