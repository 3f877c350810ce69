"""Facial regions on any model with iBUG landmarks: soft per-vertex masks for the material priors.

Computed on the model's mean shape from its 68 landmark vertices (model space, mm, +Y up, +Z out
of the face), so any topology with landmarks gets them; each mask ramps linearly from 1 to 0 over
``RAMP_MM`` at its border. Every rule is one line below.
"""

from __future__ import annotations

import numpy as np
from matplotlib.path import Path as Polygon

from facegeo.morphable_model import MorphableModel

__all__ = ["vertex_regions", "REGION_NAMES", "RAMP_MM"]

REGION_NAMES = ("forehead", "nose", "cheeks", "chin", "lips", "brows", "eyes")
RAMP_MM = 4.0


def _near(points: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
    d = np.sqrt(((points[:, None, :] - centres[None]) ** 2).sum(-1)).min(axis=1)
    return np.clip((radius + RAMP_MM - d) / RAMP_MM, 0.0, 1.0)


def _ramp(signed_mm: np.ndarray) -> np.ndarray:
    """1 where ``signed_mm`` ≥ RAMP_MM, 0 where ≤ 0."""
    return np.clip(signed_mm / RAMP_MM, 0.0, 1.0)


def vertex_regions(model: MorphableModel) -> dict[str, np.ndarray]:
    """name -> (V,) float32 soft mask in [0, 1] for :data:`REGION_NAMES`, on the face region."""
    p = model.mean_shape.astype(np.float64)
    lm = p[model.landmark_indices[:68]]
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    face = model.face_mask.astype(np.float64)
    front = _ramp(z - (lm[[0, 16], 2].mean() - 5.0))  # in front of the jaw's top: the face, not the head sides
    nose_half = 0.5 * abs(lm[35, 0] - lm[31, 0]) + 4.0  # nostril wings plus a margin
    eye_x = max(abs(lm[36, 0]), abs(lm[45, 0]))  # outer eye corners
    brow_top = lm[17:27, 1].max()

    eyes = _near(p, lm[36:48], 7.0)  # lids and canthi: within 7 mm of the eye contour
    brows = _near(p, lm[17:27], 6.0) * (1 - eyes)  # hair of the brows: 6 mm around their landmarks
    mouth_xy = Polygon(lm[48:60, :2])
    inside_lips = mouth_xy.contains_points(p[:, :2]) & (z > lm[48:60, 2].min() - 10.0)
    lips = np.maximum(inside_lips.astype(np.float64), _near(p, lm[48:60], 1.0))  # the vermilion
    nose = _near(p, lm[27:36], 9.0) * _ramp(nose_half - np.abs(x) + RAMP_MM)  # bridge, tip, wings
    forehead = _ramp(y - brow_top + 2.0) * _ramp(eye_x + 8.0 - np.abs(x)) * front  # above the brows (brows win)
    cheeks = (
        _ramp(lm[40, 1] - 6.0 - y)  # below the lower lids
        * _ramp(y - (lm[57, 1] - 2.0))  # above the lower lip line
        * _ramp(np.abs(x) - nose_half - 3.0)  # beside the nose
        * front
    )
    chin = _ramp(lm[57, 1] - 4.0 - y) * _ramp(24.0 - np.abs(x)) * front  # below the lower lip, central
    masks = {"forehead": forehead, "nose": nose, "cheeks": cheeks, "chin": chin, "lips": lips, "brows": brows, "eyes": eyes}
    # features win over the broad skin regions they lie in
    features = np.maximum.reduce([lips, brows, eyes])
    for name in ("forehead", "nose", "cheeks", "chin"):
        masks[name] = masks[name] * (1 - features)
    return {name: (m * face).astype(np.float32) for name, m in masks.items()}
