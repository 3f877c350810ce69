"""Dense landmarks in the landmark fit: MediaPipe's 468 face-mesh points as surface points of
the model, each weighed by how much it can be trusted.

A detected point i sits on the model surface at its correspondence (triangle, barycentric) of
:mod:`facegeo.landmarks.dense`. Its noise is the detector's nominal noise σ_n plus what is known
about that point: the correspondence's transfer error e_i (mm, converted to inter-ocular units
with the model's inter-ocular distance) and the detector's own spread s_i on this photo (px,
converted with the detected inter-ocular distance). Its relative precision is

    w_i = λ · σ_n² / (σ_n² + e_i² + s_i²),

with λ (:attr:`DenseSettings.weight`) the share one dense point gets of a nominal landmark's
weight: a network's 468 outputs are not 468 independent measurements, so λ·468 is about the
evidence they carry together (chosen on renders of real head scans, benchmarks/RESULTS.md).
Face-oval points below the eyes are outline points: on a turned or pitched face they mark the
silhouette, not a fixed place on the skin, so they slide along the model's occluding contour
(:mod:`facegeo.fitting.silhouette`) with :attr:`DenseSettings.contour_weight` × that weight;
the face oval's forehead points keep their place on the surface.

When dense points are used, the 16 sliding jaw points of the 88 are left out
(:attr:`DenseSettings.drop_jaw`): measured on real head scans, the jaw contour as a fixed
polyline misled the identity (issue 25: without it the error fell from 1.57× to 0.98× the mean
shape's), and the dense mesh describes the lower face better.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facegeo.errors import InputError
from facegeo.fitting.landmark_problem import SurfacePoints
from facegeo.landmarks.dense import DenseCorrespondence, points_on_mesh
from facegeo.landmarks.scheme import CHIN, EYES, JAW, inter_ocular_distance
from facegeo.morphable_model import MorphableModel
from facegeo.skin_mask import LEFT_BROW, LEFT_EYE, LIPS_INNER, LIPS_OUTER, RIGHT_BROW, RIGHT_EYE

__all__ = ["DenseSettings", "DEFAULT_DENSE", "dense_surface_points", "landmark_weights_with_dense", "EXPRESSIVE_POINTS"]

#: MediaPipe face-mesh points on the features that expressions move visibly (eyes, brows, lips):
#: the dense points whose residuals may pull expressions.
EXPRESSIVE_POINTS = np.unique(np.concatenate([LIPS_OUTER, LIPS_INNER, RIGHT_EYE, LEFT_EYE, RIGHT_BROW, LEFT_BROW]))


@dataclass(frozen=True)
class DenseSettings:
    """Knobs of the dense term (see the module docstring).

    weight: λ, the relative precision of a dense point with no known error (a nominal landmark
    has 1). nominal_noise: σ_n, inter-ocular units. contour_weight: factor for face-oval points.
    drop_jaw: leave out the 16 sliding jaw points of the 88 (the chin stays).
    features_only_expressions: only the points of the eyes, brows and lips
    (:data:`EXPRESSIVE_POINTS`) reach the expressions; the others reach the pose, the identity
    and the jaw (off by default: on the real head scan's renders it moved the error from 1.06×
    to 1.16× the mean shape's, the identity absorbing what the expressions no longer could).
    """

    weight: float = 0.25
    nominal_noise: float = 0.03
    contour_weight: float = 1.0
    drop_jaw: bool = True
    features_only_expressions: bool = False

    def __post_init__(self) -> None:
        for name in ("weight", "nominal_noise"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError("<dense settings>", name, "a finite number > 0", repr(value))
        if not (np.isfinite(self.contour_weight) and self.contour_weight >= 0):
            raise InputError("<dense settings>", "contour_weight", "a finite number >= 0", repr(self.contour_weight))


#: The default dense term.
DEFAULT_DENSE = DenseSettings()


def dense_surface_points(model: MorphableModel, points_px: np.ndarray, correspondence: DenseCorrespondence,
                         iod_px: float, settings: DenseSettings = DEFAULT_DENSE,
                         spread_px: np.ndarray | None = None) -> SurfacePoints:
    """The dense points as :class:`SurfacePoints` of the landmark problem.

    Args:
        model: the morphable model the correspondence was made for.
        points_px: (K, 2) detected points, pixels (corner-origin); NaN rows are left out.
        correspondence: where each point sits on the model (K points).
        iod_px: the detected inter-ocular distance (px), to convert ``spread_px``.
        settings: the dense term's knobs.
        spread_px: (K,) the detector's own spread of each point on this photo (px), or None.
    Returns:
        The surface points with their relative precisions (:class:`SurfacePoints`).
    """
    points = np.asarray(points_px, dtype=np.float64)
    k = len(correspondence.triangle)
    if points.shape != (k, 2):
        raise InputError("<dense landmarks>", "points", f"shape ({k}, 2) in pixels", str(points.shape))
    iod_mm = inter_ocular_distance(model.mean_shape[model.landmark_indices])
    error = (np.asarray(correspondence.transfer_error_mm, dtype=np.float64) / iod_mm) ** 2
    if spread_px is not None:
        error = error + (np.asarray(spread_px, dtype=np.float64) / max(iod_px, 1.0)) ** 2
    sigma2 = settings.nominal_noise**2
    weights = settings.weight * sigma2 / (sigma2 + error)
    on_mean = points_on_mesh(model.mean_shape, correspondence)
    eye_level = float(model.mean_shape[model.landmark_indices[EYES], 1].mean())
    outline = np.asarray(correspondence.contour, dtype=bool) & (on_mean[:, 1] < eye_level)
    weights = np.where(outline, weights * settings.contour_weight, weights)
    weights = np.where(np.isfinite(points).all(axis=1), weights, 0.0)
    expressive = np.ones(k, dtype=bool)
    if settings.features_only_expressions:  # MediaPipe's numbering
        expressive[:] = False
        expressive[EXPRESSIVE_POINTS[EXPRESSIVE_POINTS < k]] = True
    return SurfacePoints(points, correspondence.vertex_ids, correspondence.barycentric, weights, outline, expressive)


def landmark_weights_with_dense(weights: np.ndarray, settings: DenseSettings = DEFAULT_DENSE) -> np.ndarray:
    """(88,) the 88 landmarks' weights when dense points are used: the sliding jaw points at 0
    if ``settings.drop_jaw`` (the chin kept), the others unchanged (a new array)."""
    out = np.array(weights, dtype=np.float32)
    if settings.drop_jaw:
        out[JAW[JAW != CHIN]] = 0.0
    return out
