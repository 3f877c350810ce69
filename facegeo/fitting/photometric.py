"""The photometric stage of :func:`~facegeo.fitting.fit`: albedo β and SH lighting γ from the photo.

Vertex colours sampled from the photo (linearised sRGB) at visible projected vertices
(point-splat z-buffer + facing test) under a skin mask (the model's face region minus eyes,
brows and lips) are explained by albedo(β) × SH irradiance (γ, camera-space normals). The loss
is bilinear in β and γ, so it is minimised exactly by alternating regularised least squares;
residuals beyond 3 robust σ (hair, glasses, specular highlights) are dropped between rounds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from facegeo.camera import project
from facegeo.fitting.result import Fit
from facegeo.lighting import AMBIENT_WHITE, N_SH, sh_basis
from facegeo.morphable_model import MorphableModel
from facegeo.skin_mask import skin_vertex_mask
from facegeo.uv.texels import sample_bilinear
from facegeo.visibility import vertex_visibility

__all__ = ["fit_photometric", "PHOTOMETRIC_REGULARISATION"]

#: Ridge weights of the photometric least squares (β in σ units, SH coefficients).
PHOTOMETRIC_REGULARISATION = {"tex": 1e-2, "sh": 1e-3}


def fit_photometric(model: MorphableModel, fit_result: Fit, image_linear: np.ndarray, rounds: int = 4) -> None:
    """Fit β and γ (in place on ``fit_result``) by alternating regularised least squares."""
    camera = fit_result.camera
    vertices = torch.from_numpy(fit_result.vertices)
    normals = model.vertex_normals(vertices).numpy()
    visible = vertex_visibility(fit_result.vertices, model.triangles, normals, camera)
    use = np.flatnonzero(visible & skin_vertex_mask(model))
    info: dict[str, Any] = {"visible_vertices": int(visible.sum()), "skin_vertices_used": int(len(use))}
    if len(use) < 50:
        info["skipped"] = "fewer than 50 visible skin vertices"
        fit_result.info["photometric"] = info
        return
    uv = project(fit_result.vertices[use].astype(np.float64), np.eye(3), np.zeros(3), camera)
    observed = torch.from_numpy(sample_bilinear(image_linear, uv)).double()
    basis = sh_basis(torch.from_numpy(normals[use]).double())  # (N, 9)
    mean_albedo = model.tensor("mean_albedo", torch.float64)[use]
    tex_basis = model.tensor("tex_basis", torch.float64)[:, use] if model.n_tex else None
    beta = torch.zeros(model.n_tex, dtype=torch.float64)
    gamma = AMBIENT_WHITE.double().clone()
    inliers = torch.ones(len(use), dtype=torch.bool)
    sh_ridge = torch.full((N_SH,), PHOTOMETRIC_REGULARISATION["sh"], dtype=torch.float64)
    sh_ridge[0] = 0.0
    for _ in range(rounds):
        albedo = mean_albedo if tex_basis is None else mean_albedo + torch.einsum("k,kvc->vc", beta, tex_basis)
        for c in range(3):  # γ given β: per channel ridge least squares
            a = albedo[inliers, c, None] * basis[inliers]
            gamma[c] = torch.linalg.solve(a.T @ a + torch.diag(sh_ridge) * len(a), a.T @ observed[inliers, c])
        if tex_basis is not None:  # β given γ: one ridge least squares over the 3 channels
            irr = basis @ gamma.T  # (N, 3)
            design = (tex_basis[:, inliers] * irr[inliers][None]).permute(1, 2, 0).reshape(-1, model.n_tex)
            rhs = (observed[inliers] - mean_albedo[inliers] * irr[inliers]).reshape(-1)
            reg = PHOTOMETRIC_REGULARISATION["tex"] * len(rhs) * torch.eye(model.n_tex, dtype=torch.float64)
            beta = torch.linalg.solve(design.T @ design + reg, design.T @ rhs)
        albedo = mean_albedo if tex_basis is None else mean_albedo + torch.einsum("k,kvc->vc", beta, tex_basis)
        residual = (albedo * (basis @ gamma.T) - observed).norm(dim=1)
        sigma = 1.4826 * float(torch.median(residual[inliers])) + 1e-6
        inliers = residual < 3.0 * sigma
    info.update(inliers=int(inliers.sum()), rms_linear=float(residual[inliers].pow(2).mean().sqrt()))
    fit_result.beta = beta.numpy().astype(np.float32)
    fit_result.gamma = gamma.numpy().astype(np.float32)
    fit_result.info["photometric"] = info
