"""The 88-point hybrid landmark scheme: point order, mirror symmetry, weights and the loss.

Order: points 0..67 are the 68-point iBUG-300W markup (0–16 jaw from the subject's right to left,
17–21 right brow, 22–26 left brow, 27–30 nose bridge, 31–35 nostrils, 36–41 right eye, 42–47
left eye, 48–59 outer lip, 60–67 inner lip); points 68..87 are the 20 lip points of MediaPipe's
face mesh at the semantic positions of iBUG 48..67 (12 outer, 8 inner). The paper (Sec. 3.2)
adds them because 68-point detectors are unstable around the mouth; the loss therefore weights
them up and the dlib mouth points down. All weights live here, nowhere else.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from facegeo.array_namespace import is_tensor

if TYPE_CHECKING:  # torch is imported where it is used, so that the detectors' registry (and the
    import torch   # command line's --landmarks choices and help) can be read without loading it

__all__ = [
    "N_LANDMARKS",
    "N_IBUG",
    "IBUG68",
    "JAW",
    "CHIN",
    "JAW_ENDS",
    "RIGHT_BROW",
    "LEFT_BROW",
    "BROWS",
    "NOSE_BRIDGE",
    "NOSTRILS",
    "NOSE",
    "RIGHT_EYE",
    "LEFT_EYE",
    "EYES",
    "OUTER_EYE_CORNERS",
    "OUTER_LIP",
    "INNER_LIP",
    "MOUTH",
    "INNER_FACE",
    "LIP_POINTS",
    "IBUG_MIRROR",
    "HYBRID_MIRROR",
    "LANDMARK_WEIGHTS",
    "landmark_loss",
    "inter_ocular_distance",
]

N_LANDMARKS = 88
#: The iBUG-68 points: the first 68 of the 88 (and the whole of a 68-point markup).
N_IBUG = 68
IBUG68 = np.arange(0, N_IBUG)

# Named groups of the iBUG-68 markup (index arrays, valid in the 68- and the 88-point order; the
# subject's right is the image's left). Use these, not slice literals such as 17:68 or 36:48.
#: The 17 jaw-contour points (they slide along the silhouette in fitting, except the chin).
JAW = np.arange(0, 17)
CHIN = 8
#: The two ends of the jaw contour (beside the ears).
JAW_ENDS = np.array([0, 16])
RIGHT_BROW = np.arange(17, 22)
LEFT_BROW = np.arange(22, 27)
BROWS = np.arange(17, 27)
NOSE_BRIDGE = np.arange(27, 31)
NOSTRILS = np.arange(31, 36)
NOSE = np.arange(27, 36)
#: Each eye's six lid points, from the outer corner (36 right, 45 left) round.
RIGHT_EYE = np.arange(36, 42)
LEFT_EYE = np.arange(42, 48)
EYES = np.arange(36, 48)
#: The outer eye corners (right, left): the inter-ocular distance's ends.
OUTER_EYE_CORNERS = np.array([36, 45])
OUTER_LIP = np.arange(48, 60)
INNER_LIP = np.arange(60, 68)
#: dlib's 20 mouth points (outer and inner lip), which the MediaPipe lip points repeat.
MOUTH = np.arange(48, 68)
#: Every iBUG point but the jaw contour (brows, nose, eyes, mouth): the rigid inner face.
INNER_FACE = np.arange(17, 68)
#: The 20 MediaPipe lip points in the 88-point order (at the positions of :data:`MOUTH`).
LIP_POINTS = np.arange(68, 88)

#: iBUG-68 index of the mirror-symmetric point (left/right swap), an involution.
IBUG_MIRROR = np.array(
    list(range(16, -1, -1))  # jaw
    + list(range(26, 21, -1)) + list(range(21, 16, -1))  # brows
    + [27, 28, 29, 30] + [35, 34, 33, 32, 31]  # nose
    + [45, 44, 43, 42, 47, 46] + [39, 38, 37, 36, 41, 40]  # eyes
    + [54, 53, 52, 51, 50, 49, 48, 59, 58, 57, 56, 55]  # outer lip
    + [64, 63, 62, 61, 60, 67, 66, 65],  # inner lip
    dtype=np.int64,
)
#: The same for the 88-point order (lip points mirror among themselves).
HYBRID_MIRROR = np.concatenate([IBUG_MIRROR, IBUG_MIRROR[MOUTH] + 20])


def _weights() -> np.ndarray:
    w = np.ones(N_LANDMARKS, dtype=np.float32)
    w[JAW] = 0.5  # the contour is ambiguous along its own direction
    w[MOUTH] = 0.5  # dlib's mouth points: unstable (the paper's motivation)
    w[LIP_POINTS] = 3.0  # MediaPipe's lip points: weighted up
    return w


#: (88,) float32 per-point weights of the landmark loss.
LANDMARK_WEIGHTS = _weights()


def inter_ocular_distance(points: np.ndarray | torch.Tensor) -> float:
    """Distance between the outer eye corners (iBUG 36 and 45) of (≥68, 2) or (≥68, 3) points, in
    their units (pixels for detected landmarks, mm for the model's landmark vertices)."""
    if is_tensor(points):
        points = points.detach().cpu().numpy()
    right, left = np.asarray(points, dtype=np.float64)[OUTER_EYE_CORNERS]
    return float(np.linalg.norm(right - left))


def landmark_loss(
    predicted: torch.Tensor,
    target: torch.Tensor,
    weights: torch.Tensor | np.ndarray | None = None,
    scale: float | torch.Tensor = 1.0,
) -> torch.Tensor:
    """Weighted mean squared landmark distance, normalised by ``scale``².

    Args:
        predicted: (..., 88, 2) projected model landmarks, pixels.
        target: (88, 2) or (..., 88, 2) detected landmarks, pixels; NaN rows are ignored
            (weight 0).
        weights: (88,) per-point weights (default :data:`LANDMARK_WEIGHTS`).
        scale: a face size in pixels (e.g. the inter-ocular distance) so the loss is
            resolution-independent; a float or a (...) tensor (one per target set).
    Returns:
        (...) tensor: Σ w_i ‖p_i − q_i‖² / (Σ w_i · scale²).
    """
    import torch

    w = torch.as_tensor(LANDMARK_WEIGHTS if weights is None else weights, dtype=predicted.dtype)
    valid = torch.isfinite(target).all(-1)
    w = torch.where(valid, w, torch.zeros_like(w))
    target = torch.where(valid[..., None], target, torch.zeros_like(target))
    sq = ((predicted - target) ** 2).sum(-1)
    return (sq * w).sum(-1) / (w.sum(-1) * scale * scale)
