"""A picture for checking a fit: the fitted mesh's visible wireframe over the photo, detected
landmarks (green dots) and fitted landmarks (red crosses), jaw points in yellow."""

from __future__ import annotations

import cv2
import numpy as np

from facegeo.camera import project
from facegeo.fitting import Fit
from facegeo.morphable_model import MorphableModel
from facegeo.normals import vertex_normals
from facegeo.visibility import vertex_visibility

__all__ = ["draw_overlay"]


def draw_overlay(image: np.ndarray, fit: Fit, model: MorphableModel, wire_alpha: float = 0.35) -> np.ndarray:
    """(H, W, 3) uint8 RGB image with the fit drawn over ``image`` (same size, sRGB)."""
    canvas = np.ascontiguousarray(image.copy())
    normals = vertex_normals(fit.vertices, model.triangles)
    visible = vertex_visibility(fit.vertices, model.triangles, normals, fit.camera)
    uv = project(fit.vertices.astype(np.float64), np.eye(3), np.zeros(3), fit.camera)
    tri = model.triangles[visible[model.triangles].all(axis=1)]
    shift = 4  # sub-pixel precision for cv2 drawing (coordinates × 16)

    def to_cv(p: np.ndarray) -> np.ndarray:  # corner-origin pixels -> cv2's fixed point
        return np.round((p - 0.5) * (1 << shift)).astype(np.int32)

    wire = canvas.copy()
    cv2.polylines(wire, list(to_cv(uv[tri])), True, (200, 200, 255), 1, cv2.LINE_AA, shift)
    canvas = cv2.addWeighted(wire, wire_alpha, canvas, 1.0 - wire_alpha, 0.0)
    radius = max(2, int(round(max(image.shape[:2]) / 300)))
    for i, (p, q) in enumerate(zip(fit.landmarks, fit.landmarks_fitted)):
        if np.all(np.isfinite(p)):
            colour = (255, 220, 0) if i < 17 else (0, 220, 0)
            cv2.circle(canvas, tuple(to_cv(p)), radius << shift, colour, -1, cv2.LINE_AA, shift)
        c = to_cv(q)
        d = (radius + 1) << shift
        cv2.line(canvas, (c[0] - d, c[1] - d), (c[0] + d, c[1] + d), (255, 40, 40), 1, cv2.LINE_AA, shift)
        cv2.line(canvas, (c[0] - d, c[1] + d), (c[0] + d, c[1] - d), (255, 40, 40), 1, cv2.LINE_AA, shift)
    return canvas
