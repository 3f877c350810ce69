"""Validation faces with 3-D ground truth for the landmark fit, beyond faces of the model itself.

A face here is an ICT-FaceKit instance with α ~ N(0, I) and a *realistic* expression mix (one of
a few everyday expressions — neutral, smile, laugh, talk, surprise, frown, pucker — with
ARKit-style weights in [0, 1], left/right jitter and a few small extra shapes), plus a smooth
random deformation *outside the model space* (Gaussian bumps along the normals, 1.0 mm RMS over
the face by default, bumps 20–50 mm wide: the size of what a linear identity model misses of a
real face), posed (yaw ±50°, pitch ±20°, roll ±15°) in front of a 512 × 512 camera. Its 88
landmarks are the projected landmark vertices plus detector-like noise: independent Gaussian
noise per point (1.5 % of the inter-ocular distance / √w with w the point's weight in
LANDMARK_WEIGHTS: 2.1 % on the jaw and dlib's mouth, 0.9 % on MediaPipe's lips) and a shared
offset per feature group (1 %), with the 20 MediaPipe lip points noised independently of dlib's
mouth points. ``FaceSet(kind="model")`` gives noiseless faces of
the model itself (no deformation, no noise) for the recovery bar.

Metrics (:func:`face_errors`), all in mm after the best similarity transform of the fitted
face region onto the truth: the RMS error over the face region, the same for the mean shape
(the baseline), and the depth error of the upper lip, lower lip and chin relative to the nose
tip (along the truth's model z axis).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from facegeo import Camera, MorphableModel, project
from facegeo.camera import rotation_from_euler
from facegeo.landmarks.scheme import BROWS, EYES, LANDMARK_WEIGHTS, LIP_POINTS, MOUTH, NOSE, inter_ocular_distance

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_fitting import similarity_align  # noqa: E402  (one definition of the 3D alignment)

__all__ = ["ValidationFace", "make_faces", "face_errors", "EXPRESSIONS", "DEPTH_POINTS"]

CAMERA = Camera.for_image(512, 512)

#: Everyday expressions as (blendshape name stem, weight range); ``_L``/``_R`` pairs get both
#: sides with a little asymmetry.
EXPRESSIONS: dict[str, list[tuple[str, float, float]]] = {
    "neutral": [],
    "smile": [("mouthSmile", 0.3, 0.9), ("cheekSquint", 0.0, 0.4), ("eyeSquint", 0.0, 0.3)],
    "laugh": [("mouthSmile", 0.5, 1.0), ("jawOpen", 0.15, 0.45), ("cheekSquint", 0.2, 0.6), ("eyeSquint", 0.2, 0.6), ("mouthUpperUp", 0.0, 0.4)],
    "talk": [("jawOpen", 0.05, 0.35), ("mouthFunnel", 0.0, 0.3), ("mouthLowerDown", 0.0, 0.3)],
    "surprise": [("browInnerUp", 0.3, 0.9), ("browOuterUp", 0.3, 0.9), ("eyeWide", 0.2, 0.7), ("jawOpen", 0.1, 0.4)],
    "frown": [("browDown", 0.3, 0.8), ("mouthFrown", 0.2, 0.7), ("mouthPress", 0.0, 0.4)],
    "pucker": [("mouthPucker", 0.3, 0.9), ("mouthFunnel", 0.0, 0.3)],
}
#: iBUG points whose depth relative to the nose tip (30) is checked: upper lip, lower lip, chin.
DEPTH_POINTS = {"upper lip": 51, "lower lip": 57, "chin": 8}
_GROUPS = [BROWS, EYES, NOSE, MOUTH, LIP_POINTS]


@dataclass
class ValidationFace:
    """One face: ``shape`` (V, 3) mm model space (the truth), ``landmarks`` (88, 2) px,
    ``alpha``, ``delta`` (the model part of the truth), ``expression`` its name, ``yaw`` deg."""

    shape: np.ndarray
    landmarks: np.ndarray
    alpha: np.ndarray
    delta: np.ndarray
    expression: str
    yaw: float


def _expression(model: MorphableModel, rng: np.random.Generator, name: str) -> np.ndarray:
    names = list(model.expression_names)
    delta = np.zeros(model.n_exp, np.float32)
    for stem, lo, hi in EXPRESSIONS[name]:
        value = rng.uniform(lo, hi)
        for side in ("_L", "_R"):
            if stem + side in names:
                delta[names.index(stem + side)] = np.clip(value + rng.normal(0, 0.08), 0, 1)
        if stem in names:
            delta[names.index(stem)] = value
    for k in rng.choice(model.n_exp, size=rng.integers(0, 4), replace=False):  # a few small extras
        if not names[k].startswith(("mouthClose", "eyeLook")):
            delta[k] = max(delta[k], rng.uniform(0.0, 0.25))
    return delta


def _smooth_deformation(model: MorphableModel, shape: np.ndarray, rng: np.random.Generator, rms_mm: float) -> np.ndarray:
    """(V, 3) Gaussian bumps along the vertex normals, scaled to ``rms_mm`` over the face."""
    normals = model.vertex_normals(torch.from_numpy(shape)).numpy()
    face = np.flatnonzero(model.face_mask)
    field = np.zeros(len(shape))
    for _ in range(8):
        centre = shape[rng.choice(face)]
        radius = rng.uniform(20.0, 50.0)
        field += rng.normal() * np.exp(-((shape - centre) ** 2).sum(1) / (2 * radius**2))
    field *= rms_mm / max(np.sqrt(np.mean(field[face] ** 2)), 1e-9)
    return normals * field[:, None]


def _detector_noise(landmarks: np.ndarray, rng: np.random.Generator, level: float) -> np.ndarray:
    """Independent noise of ``level`` × inter-ocular distance / √w_i per point (w_i the relative
    precisions of :data:`LANDMARK_WEIGHTS`: the jaw and dlib's mouth points are noisier, the
    MediaPipe lip points more precise) plus one shared offset of ``level`` / 1.5 per feature
    group (brows, eyes, nose, mouth; dlib's and MediaPipe's mouth points separately)."""
    iod = inter_ocular_distance(landmarks)
    sigma = level * iod / np.sqrt(LANDMARK_WEIGHTS.astype(np.float64))
    noisy = landmarks + rng.normal(0, 1, landmarks.shape) * sigma[:, None]
    for group in _GROUPS:
        noisy[list(group)] += rng.normal(0, level / 1.5 * iod, 2)
    return noisy


def make_faces(model: MorphableModel, count: int, seed: int, kind: str = "real-like", deformation_mm: float = 1.0,
               noise: float = 0.015) -> list[ValidationFace]:
    """``count`` faces: ``kind="real-like"`` (expression mixes, ``deformation_mm`` RMS of smooth
    deformation, detector noise of ``noise`` × inter-ocular distance) or ``"model"`` (noiseless
    faces of the model itself with the same expression mixes)."""
    rng = np.random.default_rng(seed)
    faces = []
    for i in range(count):
        expression = list(EXPRESSIONS)[i % len(EXPRESSIONS)]
        alpha = rng.normal(0, 1, model.n_id).astype(np.float32)
        delta = _expression(model, rng, expression)
        shape = model.shape(torch.from_numpy(alpha), torch.from_numpy(delta)).numpy()
        if kind == "real-like":
            shape = shape + _smooth_deformation(model, shape, rng, deformation_mm)
        yaw = rng.uniform(-50, 50)
        rotation = rotation_from_euler(yaw, rng.uniform(-20, 20), rng.uniform(-15, 15))
        translation = np.array([rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(-800, -500)])
        landmarks = project(shape[model.landmark_indices].astype(np.float64), rotation, translation, CAMERA)
        if kind == "real-like":
            landmarks = _detector_noise(landmarks, rng, noise)
        faces.append(ValidationFace(shape.astype(np.float32), landmarks, alpha, delta, expression, float(yaw)))
    return faces


def face_errors(model: MorphableModel, fitted: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """3-D errors (mm) of ``fitted`` (V, 3) against ``truth`` (V, 3), both model space:
    ``rms`` over the face region after similarity alignment on it, ``mean_rms`` the same for the
    mean shape, and ``depth_<point>`` the error of each :data:`DEPTH_POINTS` depth relative to
    the nose tip."""
    face = model.face_mask
    aligned = similarity_align(fitted[face], truth[face])
    out = {"rms": float(np.sqrt(((aligned - truth[face]) ** 2).sum(1).mean()))}
    mean_aligned = similarity_align(model.mean_shape[face], truth[face])
    out["mean_rms"] = float(np.sqrt(((mean_aligned - truth[face]) ** 2).sum(1).mean()))
    full = np.zeros_like(truth, dtype=np.float64)
    full[face] = aligned
    index = model.landmark_indices
    nose = index[30]
    for name, point in DEPTH_POINTS.items():
        v = index[point]
        out[f"depth_{name}"] = float(abs((full[v, 2] - full[nose, 2]) - (truth[v, 2] - truth[nose, 2])))
    return out
