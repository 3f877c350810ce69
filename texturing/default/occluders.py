"""An occluder's fringe: seen skin within ``settings.fringe_mm`` of the unseen whose de-lit colour
the reliably seen skin's robust Gaussian (log RGB) puts beyond its ``settings.fringe_significance``
χ² quantile is what the photo's mask let through at its edge (a sideburn's last strands, a frame's
rim) and is treated as unseen too; in a greyscale photo, whose mask has no chroma to keep hair
out, wherever it is seen (:func:`occluder_fringe`).
"""

from __future__ import annotations

import numpy as np

from facegeo.robust_gaussian import chi2_quantile, mahalanobis_squared, robust_gaussian
from facegeo.texturing.backend import TextureContext
from facegeo.texturing.default.settings import DefaultSettings
from facegeo.texturing.default.texels import skin_texels, subsample
from facegeo.texturing.image_filters import gaussian_blur

__all__ = ["occluder_fringe"]


def occluder_fringe(lin: np.ndarray, shading: np.ndarray, w: np.ndarray, inner: np.ndarray, fit_mask: np.ndarray,
                    ctx: TextureContext, reach: float, settings: DefaultSettings) -> np.ndarray:
    """(S, S) float32 in [0, 1]: 1 on the seen skin's texels (``w`` (S, S) > 0) within
    ``reach`` mm (``inner``: :func:`~facegeo.texturing.default.reliability.inner_distance` of
    ``w > 0.5``, (S, S) mm) of a texel not seen whose de-lit colour (``lin`` (S, S, 3) linear
    RGB over ``shading`` (S, S)) is not skin's: its log RGB beyond the ``settings.fringe_significance`` χ² quantile of a robust
    Gaussian of the reliably seen skin (``fit_mask`` (S, S) bool) farther inside, feathered over
    S/512 texels. A mask's edge lets through the fringe of what it masks (a sideburn's last
    strands, a frame's rim), stretched over many texels where the surface turns away; inside
    the seen region the same colours are the face's own (a mole, a beard) and are kept, except
    in a greyscale photo (``reach`` = ∞), whose skin mask had no chroma to keep hair out."""
    def log_delit(rows: np.ndarray) -> np.ndarray:
        return np.log(np.maximum(lin.reshape(-1, 3)[rows] / shading.reshape(-1)[rows, None], 1e-4))

    source = np.flatnonzero((fit_mask & (inner > settings.fringe_mm)).ravel())
    if len(source) < 100:
        return np.zeros(w.shape, np.float32)
    mean, cov = robust_gaussian(log_delit(subsample(source, settings.fringe_samples)))
    near = np.flatnonzero(((w > 0) & skin_texels(ctx) & (inner < reach)).ravel())
    outlier = np.zeros(w.shape, np.float32)
    outlier.reshape(-1)[near] = mahalanobis_squared(log_delit(near), mean, cov) > chi2_quantile(settings.fringe_significance, 3)
    return np.clip(gaussian_blur(outlier, max(1.0, ctx.size / 512.0)) * 2.0, 0.0, 1.0).astype(np.float32)
