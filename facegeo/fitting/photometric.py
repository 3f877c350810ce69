"""The photometric stage of :func:`~facegeo.fitting.fit`: albedo β and SH lighting γ from the photo.

Vertex colours sampled from the photo (linearised sRGB) at visible projected vertices
(point-splat z-buffer + facing test) under a skin mask (the model's face region minus eyes,
brows and lips) are explained by albedo(β) × SH irradiance (γ, camera-space normals). The loss
is bilinear in β and γ, so it is minimised exactly by alternating regularised least squares;
residuals beyond 3 robust σ (hair, glasses, specular highlights) are dropped between rounds.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from facegeo.camera import project
from facegeo.fitting.result import Fit
from facegeo.lighting import AMBIENT_WHITE, N_SH, sh_basis
from facegeo.morphable_model import MorphableModel
from facegeo.normals import vertex_normals
from facegeo.skin_mask import skin_vertex_mask
from facegeo.uv.texels import sample_bilinear
from facegeo.visibility import vertex_visibility

__all__ = ["fit_photometric", "PHOTOMETRIC_REGULARISATION"]

#: Ridge weights of the photometric least squares (β in σ units, SH coefficients).
PHOTOMETRIC_REGULARISATION = {"tex": 1e-2, "sh": 1e-3}


def fit_photometric(model: MorphableModel, fit_result: Fit, image_linear: np.ndarray, rounds: int = 4) -> Fit:
    """``fit_result`` with β and γ fitted by alternating regularised least squares, and the
    stage's statistics as ``info["photometric"]`` (a new :class:`Fit`; β and γ as they were
    where too few skin vertices are visible)."""
    camera = fit_result.camera
    normals = vertex_normals(fit_result.vertices, model.triangles)
    visible = vertex_visibility(fit_result.vertices, model.triangles, normals, camera)
    use = np.flatnonzero(visible & skin_vertex_mask(model))
    info: dict[str, Any] = {"visible_vertices": int(visible.sum()), "skin_vertices_used": int(len(use))}
    if len(use) < 50:
        info["skipped"] = "fewer than 50 visible skin vertices"
        return replace(fit_result, info={**fit_result.info, "photometric": info})
    uv = project(fit_result.vertices[use].astype(np.float64), np.eye(3), np.zeros(3), camera)
    observed = sample_bilinear(image_linear, uv).astype(np.float64)
    basis = sh_basis(normals[use])  # (N, 9) float64
    mean_albedo = model.mean_albedo[use].astype(np.float64)
    tex_basis = model.tex_basis[:, use].astype(np.float64) if model.n_tex else None
    beta = np.zeros(model.n_tex)
    gamma = AMBIENT_WHITE.astype(np.float64)
    inliers = np.ones(len(use), dtype=bool)
    sh_ridge = np.full(N_SH, PHOTOMETRIC_REGULARISATION["sh"])
    sh_ridge[0] = 0.0
    for _ in range(rounds):
        albedo = mean_albedo if tex_basis is None else mean_albedo + np.einsum("k,kvc->vc", beta, tex_basis)
        for c in range(3):  # γ given β: per channel ridge least squares
            a = albedo[inliers, c, None] * basis[inliers]
            gamma[c] = np.linalg.solve(a.T @ a + np.diag(sh_ridge) * len(a), a.T @ observed[inliers, c])
        if tex_basis is not None:  # β given γ: one ridge least squares over the 3 channels
            irr = basis @ gamma.T  # (N, 3)
            design = (tex_basis[:, inliers] * irr[inliers][None]).transpose(1, 2, 0).reshape(-1, model.n_tex)
            rhs = (observed[inliers] - mean_albedo[inliers] * irr[inliers]).reshape(-1)
            reg = PHOTOMETRIC_REGULARISATION["tex"] * len(rhs) * np.eye(model.n_tex)
            beta = np.linalg.solve(design.T @ design + reg, design.T @ rhs)
        albedo = mean_albedo if tex_basis is None else mean_albedo + np.einsum("k,kvc->vc", beta, tex_basis)
        residual = np.linalg.norm(albedo * (basis @ gamma.T) - observed, axis=1)
        sigma = 1.4826 * float(_lower_median(residual[inliers])) + 1e-6
        inliers = residual < 3.0 * sigma
    info.update(inliers=int(inliers.sum()), rms_linear=float(np.sqrt(np.mean(residual[inliers] ** 2))))
    return replace(fit_result, beta=beta.astype(np.float32), gamma=gamma.astype(np.float32),
                   info={**fit_result.info, "photometric": info})


def _lower_median(values: np.ndarray) -> float:
    """The lower median of (N,) values (the smaller middle value for an even count): the robust
    scale's convention in this stage."""
    return float(np.partition(values, (len(values) - 1) // 2)[(len(values) - 1) // 2])
