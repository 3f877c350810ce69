"""An occluder's fringe: seen skin within ``settings.fringe_mm`` of the unseen whose de-lit colour
the reliably seen skin's robust Gaussian (log RGB) puts beyond its ``settings.fringe_significance``
χ² quantile is what the photo's mask let through at its edge (a sideburn's last strands, a frame's
rim) and is treated as unseen too; in a greyscale photo, whose mask has no chroma to keep hair
out, wherever it is seen (:func:`occluder_fringe`). A greyscale photo's fringe is told by its
luminance alone, against the reliably seen skin next to it (:func:`grey_fringe`): over the
whole face the de-lit skin's luminance varies more (shading residue, a beard) than a hair
fringe's or a dark padding's step from the skin at the edge, which the global test lets through.
"""

from __future__ import annotations

import numpy as np

from facegeo.colour import luminance
from facegeo.robust_gaussian import chi2_quantile, mahalanobis_squared, robust_gaussian
from facegeo.texturing.backend import TextureContext
from facegeo.texturing.default.settings import DefaultSettings
from facegeo.texturing.default.texels import skin_texels, smoothstep, subsample
from facegeo.texturing.image_filters import gaussian_blur, masked_blur

__all__ = ["grey_fringe", "occluder_fringe"]


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
    return _feathered(outlier, ctx)


def grey_fringe(lin: np.ndarray, shading: np.ndarray, w: np.ndarray, inner: np.ndarray, fit_mask: np.ndarray,
                ctx: TextureContext, settings: DefaultSettings) -> np.ndarray:
    """(S, S) float32 in [0, 1]: 1 on the seen skin's texels (``w`` (S, S) > 0) within
    ``settings.fringe_mm`` of a texel not seen (``inner``, (S, S) mm, as :func:`occluder_fringe`)
    whose de-lit log-luminance (``lin`` (S, S, 3) linear RGB over ``shading`` (S, S)) departs from
    the local level of the reliably seen skin farther inside (``fit_mask`` (S, S) bool beyond
    ``settings.fringe_mm``; a masked Gaussian of σ ``settings.fringe_local_mm`` of surface) by more
    than the ``settings.fringe_significance`` χ² quantile (1 degree of freedom) of that skin's own
    departures from it; feathered over S/512 texels. For a greyscale photo, whose mask had no
    chroma to tell a hair fringe, a collar, the background at the silhouette or an image's dark
    padding from skin at its edge: their step in luminance from the skin beside them is what
    tells them, where the face's whole spread of luminance does not. Texels with too little of
    that skin near (its Gaussian weight below ``settings.highlight_reference_support``) are not
    judged."""
    log_l = np.log(np.maximum(luminance(lin) / np.maximum(shading, 1e-6), 1e-4)).astype(np.float32)
    source = fit_mask & (inner > settings.fringe_mm)
    if source.sum() < 100:
        return np.zeros(w.shape, np.float32)
    sigma = max(1.0, settings.fringe_local_mm / ctx.median_texel_mm)
    level = masked_blur(log_l, source, sigma)
    support = gaussian_blur(source.astype(np.float32), sigma)
    departure = log_l - level
    d = departure[source]
    spread = 1.4826 * float(np.median(np.abs(d - np.median(d)))) + 1e-6
    near = (w > 0) & skin_texels(ctx) & (inner < settings.fringe_mm) & (support >= settings.highlight_reference_support)
    # a fringe fades into the skin over several texels (a photo pixel is many texels where the face
    # is small): from settings.fringe_soft_sigmas on the texel is partly the fringe's, so that the kept
    # skin does not end on a darker ramp that the fill's blend by reliability turns into a line
    lo, hi = settings.fringe_soft_sigmas, float(np.sqrt(chi2_quantile(settings.fringe_significance, 1)))
    outlier = np.where(near, smoothstep((np.abs(departure) / spread - lo) / max(hi - lo, 1e-6)), 0.0).astype(np.float32)
    return _feathered(outlier, ctx)


def _feathered(outlier: np.ndarray, ctx: TextureContext) -> np.ndarray:
    """(S, S) float32 in [0, 1]: ``outlier`` (S, S) spread over S/512 texels (σ, at least one)
    and doubled, so that a fringe's whole width is taken, not its core."""
    return np.clip(gaussian_blur(outlier, max(1.0, ctx.size / 512.0)) * 2.0, 0.0, 1.0).astype(np.float32)
