"""Hands in a photo: MediaPipe's palm detector and hand landmark model, and the mask of the hands.

A hand in front of a face is skin-coloured, so the skin mask's colour model
(:mod:`facegeo.skin_mask`) lets it through; this module finds it by shape instead. Two bundled
models (``assets/mediapipe``, Apache-2.0, extracted from the ``mediapipe==0.10.14`` wheel by
``assets/mediapipe/extract_mediapipe_models.py``), run with LiteRT through the loader of
:mod:`facegeo.landmarks.mediapipe_mesh`:

``palm_detection_lite.tflite`` -- BlazePalm (lite)
    Input (1, 192, 192, 3) float32 RGB in [0, 1], the whole photo letterboxed to a square
    (MediaPipe's ``palm_detection_cpu.pbtxt``). Outputs (1, 2016, 18) box + 7 keypoints (wrist
    centre, index, middle, ring and pinky knuckles, thumb base, thumb knuckle) and (1, 2016, 1)
    score logits, decoded like BlazeFace (:func:`facegeo.landmarks.mediapipe_mesh.ssd_detect`)
    against 2016 SSD anchors (4 layers, strides 8/16/16/16, 24×24×2 + 12×12×6); scores ≥ 0.5,
    weighted NMS at IoU 0.3.
``hand_landmark_lite.tflite`` -- 21 hand landmarks (lite)
    Input (1, 224, 224, 3) float32 RGB in [0, 1]: a square crop rotated so that the hand points
    up. Its ROI is MediaPipe's ``palm_detection_detection_to_roi``: rotation from the wrist
    keypoint to the middle knuckle (target 90°), the box centre shifted by half the box height
    towards the fingers, a square of 2.6 × the larger box side. Outputs (1, 63) 21 × (x, y, z)
    in crop pixels, (1, 1) hand presence (a probability: the model ends in a sigmoid),
    (1, 1) handedness and (1, 63) world coordinates (not used). Hands with presence < 0.5 are
    dropped.

Why the lite models (4 MB against the full ones' 7.8 MB): on ``benchmarks/bench_albedo.py``'s
composited hands (flat skin-coloured mittens beside a cheek) the lite palm detector scores 0.66
and 0.65 (landmark presence 0.84 and 0.57), the full one 0.96 and 0.37 (the second below
MediaPipe's 0.5); on the photos without a hand (the bundled astronaut, matplotlib's Grace
Hopper, the benchmark's frontal scene) no lite detection reaches 0.3, while the full detector
fires at 0.75 and 0.78 on two faces (rejected by the landmark model's presence, 0.00). On the
18 photos of scikit-image's ``skimage.data`` (no bare hand in any) the lite palm detector fires
(≥ 0.5) on 6, 7 detections up to 0.84 (a cat, cells, a retina, a motorcycle, the Hubble deep
field, the cameraman); the landmark model's presence is at most 0.015 on them, so no hand is
reported.

Landmark order (MediaPipe's): 0 wrist; thumb 1–4; index 5–8; middle 9–12; ring 13–16;
pinky 17–20 (knuckle to tip). Coordinates: pixels, the centre of the top-left pixel at (0, 0).

:func:`hand_mask` rasterises the hands: for each finger the convex hull of its chain from the
wrist to the tip plus a point :data:`HEEL` palm lengths beyond the wrist (so the five hulls
together cover the heel of the palm, the palm and the fingers), dilated by :data:`HAND_MARGIN` ×
the palm length (wrist to middle knuckle, ~9 cm on an adult hand: ~1.8 cm, half a finger's width
plus about a centimetre for the landmarks' error and the soft edge). A forearm is not found.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from facegeo.landmarks.mediapipe_mesh import MediaPipeFaceMesh, _check_image, _Model, roi_crop, ssd_anchors, ssd_detect

__all__ = ["Hand", "HandDetector", "hand_mask", "default_hand_detector", "FINGER_CHAINS", "HAND_MARGIN", "HEEL", "MIN_PALM_SCORE",
           "PALM_ASSET", "HAND_LANDMARK_ASSET"]

PALM_ASSET = "mediapipe/palm_detection_lite.tflite"
HAND_LANDMARK_ASSET = "mediapipe/hand_landmark_lite.tflite"
PALM_SIZE = 192
LANDMARK_SIZE = 224
N_HAND = 21
#: Output tensor names of the hand landmark model (two outputs share each shape).
LANDMARK_OUTPUTS = {"landmarks": "Identity", "presence": "Identity_1", "handedness": "Identity_2"}
#: BlazePalm anchors (MediaPipe's ``palm_detection_cpu.pbtxt``).
PALM_ANCHOR_OPTIONS = dict(input_size=(PALM_SIZE, PALM_SIZE), strides=(8, 16, 16, 16), min_scale=0.1484375,
                           max_scale=0.75, anchor_offset=(0.5, 0.5), aspect_ratios=(1.0,),
                           interpolated_scale_aspect_ratio=1.0, fixed_anchor_size=True)
#: ROI from a palm detection: square side / larger box side, and the shift towards the fingers
#: in box heights (MediaPipe's ``palm_detection_detection_to_roi``).
ROI_SCALE = 2.6
ROI_SHIFT = 0.5
#: Each finger's landmark chain from the wrist to the tip.
FINGER_CHAINS = ((0, 1, 2, 3, 4), (0, 5, 6, 7, 8), (0, 9, 10, 11, 12), (0, 13, 14, 15, 16), (0, 17, 18, 19, 20))
#: Palm detections below this score are not tried (MediaPipe's default); the landmark model's
#: presence ≥ 0.5 is the second gate.
MIN_PALM_SCORE = 0.5
#: The hulls are dilated by this fraction of the palm length (landmark 0 to 9).
HAND_MARGIN = 0.2
#: Each hull also holds the point this many palm lengths beyond the wrist, away from the middle
#: knuckle (the heel of the palm and the wrist, which the landmarks do not reach).
HEEL = 0.4


@dataclass(frozen=True)
class Hand:
    """One hand: ``landmarks`` (21, 3) float32 x, y px and z (crop depth scaled like x, relative
    to the wrist, negative towards the camera), ``presence`` in [0, 1], ``score`` of the palm
    detection, ``roi`` (4,) float32 centre x, centre y, side px and rotation (radians,
    clockwise) of the crop the landmarks came from."""

    landmarks: np.ndarray
    presence: float
    score: float
    roi: np.ndarray

    @property
    def palm_length(self) -> float:
        """Distance from the wrist to the middle knuckle in pixels."""
        return float(np.linalg.norm(self.landmarks[9, :2] - self.landmarks[0, :2]))


class HandDetector:
    """BlazePalm detection + the 21-point hand landmark model on one RGB photo (models loaded on
    first use; ``palm_path`` / ``landmark_path`` default to the bundled ones)."""

    def __init__(self, palm_path: str | Path | None = None, landmark_path: str | Path | None = None, *,
                 min_detection_score: float = MIN_PALM_SCORE, nms_iou: float = 0.3, min_presence: float = 0.5,
                 max_hands: int = 4, num_threads: int | None = 1):
        self.palm_path = None if palm_path is None else Path(palm_path)
        self.landmark_path = None if landmark_path is None else Path(landmark_path)
        self.min_detection_score = float(min_detection_score)
        self.nms_iou = float(nms_iou)
        self.min_presence = float(min_presence)
        self.max_hands = int(max_hands)
        self.num_threads = num_threads
        self.anchors = ssd_anchors(**PALM_ANCHOR_OPTIONS)
        self._palm: _Model | None = None
        self._landmarks: _Model | None = None

    @property
    def palm_model(self) -> _Model:
        if self._palm is None:
            n = self.anchors.shape[0]
            self._palm = _Model(self.palm_path or MediaPipeFaceMesh._asset(PALM_ASSET), (1, PALM_SIZE, PALM_SIZE, 3),
                                {"boxes": (1, n, 18), "scores": (1, n, 1)}, self.num_threads)
        return self._palm

    @property
    def landmark_model(self) -> _Model:
        if self._landmarks is None:
            self._landmarks = _Model(self.landmark_path or MediaPipeFaceMesh._asset(HAND_LANDMARK_ASSET),
                                     (1, LANDMARK_SIZE, LANDMARK_SIZE, 3),
                                     {"landmarks": (1, N_HAND * 3), "presence": (1, 1), "handedness": (1, 1)},
                                     self.num_threads, LANDMARK_OUTPUTS)
        return self._landmarks

    def palms(self, image: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, float]]:
        """Palm detections (box (4,) x0, y0, x1, y1; keypoints (7, 2); score), best first."""
        return ssd_detect(self.palm_model, image, PALM_SIZE, self.anchors, (0.0, 1.0), 7,
                          self.min_detection_score, self.nms_iou)

    @staticmethod
    def roi_from_palm(box: np.ndarray, keypoints: np.ndarray) -> tuple[np.ndarray, float, float]:
        """MediaPipe's hand ROI of a palm detection: (centre (2,) px, side px, angle rad)."""
        x0, y0, x1, y1 = (float(v) for v in box)
        w, h = x1 - x0, y1 - y0
        d = keypoints[2].astype(np.float64) - keypoints[0]
        angle = math.pi / 2 - math.atan2(-float(d[1]), float(d[0]))
        # shift by ROI_SHIFT box heights along the hand's "up" (the rotated -y axis)
        centre = np.array([(x0 + x1) / 2 + ROI_SHIFT * h * math.sin(angle), (y0 + y1) / 2 - ROI_SHIFT * h * math.cos(angle)])
        return centre, ROI_SCALE * max(w, h), angle

    def landmarks_in_roi(self, image: np.ndarray, centre: np.ndarray, side: float, angle: float) -> tuple[np.ndarray, float]:
        """The 21 landmarks (21, 3) float32 px of the hand in a rotated square ROI, and its presence."""
        crop, to_image = roi_crop(image, centre, side, angle, LANDMARK_SIZE)
        out = self.landmark_model((crop.astype(np.float32) / 255.0)[None])
        raw = out["landmarks"].reshape(N_HAND, 3).astype(np.float64)
        xy = raw[:, :2] @ to_image[:, :2].T + to_image[:, 2] - 0.5
        z = raw[:, 2] * (side / LANDMARK_SIZE)
        return np.concatenate([xy, z[:, None]], axis=1).astype(np.float32), float(out["presence"].ravel()[0])

    def __call__(self, image: np.ndarray) -> list[Hand]:
        """The hands in an (H, W, 3) uint8 RGB photo (at most ``max_hands``, best palm first)."""
        _check_image(image)
        hands = []
        for box, keypoints, score in self.palms(image)[: self.max_hands]:
            centre, side, angle = self.roi_from_palm(box, keypoints)
            landmarks, presence = self.landmarks_in_roi(image, centre, side, angle)
            if presence >= self.min_presence and np.isfinite(landmarks).all():
                hands.append(Hand(landmarks, presence, score, np.array([*centre, side, angle], np.float32)))
        return hands


@functools.cache
def default_hand_detector() -> HandDetector:
    """The shared :class:`HandDetector` with the bundled models (loaded once per process)."""
    return HandDetector()


def hand_mask(shape: tuple[int, int], hands: list[Hand], margin: float = HAND_MARGIN) -> np.ndarray:
    """(H, W) bool mask of ``hands`` in an image of ``shape`` (H, W): the convex hull of each
    finger's chain (:data:`FINGER_CHAINS`) and the heel point (:data:`HEEL`) filled and dilated by
    ``margin`` × the palm length."""
    H, W = shape
    out = np.zeros((H, W), np.uint8)
    for hand in hands:
        hull = np.zeros((H, W), np.uint8)
        p = hand.landmarks[:, :2].astype(np.float64)
        heel = p[0] + HEEL * (p[0] - p[9])  # the wrist landmark is at the crease: the palm's heel is beyond it
        for chain in FINGER_CHAINS:
            points = np.round(np.vstack([heel, p[list(chain)]]) * 16).astype(np.int32)
            cv2.fillConvexPoly(hull, cv2.convexHull(points), 1, lineType=cv2.LINE_8, shift=4)
        r = max(1, int(round(margin * hand.palm_length)))
        out |= cv2.dilate(hull, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    return out.astype(bool)
