"""Highlights: bright spots of the de-lit skin, treated as unseen (filled) and the specular map's
evidence.

De-lit luminance above ``settings.highlight_ratio`` × its neighbourhood's (Gaussian, σ = S/48
texels, ~6 mm at 1K, re-estimated without the first pass's candidates; the reliable skin's, and
the seen texels' where no reliable skin is near: ``settings.highlight_reference_support``), over a
patch (``settings.highlight_patch_mm``) or, on a narrower spot, whiter than the neighbourhood
(:func:`white_share`, ``settings.highlight_white_share``: not the skin between a beard's hairs).
"""

from __future__ import annotations

import cv2
import numpy as np

from facegeo.colour import channel_sum, luminance
from facegeo.texturing.backend import TextureContext
from facegeo.texturing.default.settings import DefaultSettings
from facegeo.texturing.image_filters import gaussian_blur, masked_blur

__all__ = ["highlights", "white_share"]


def highlights(delit_lum: np.ndarray, lin: np.ndarray, shading: np.ndarray, w: np.ndarray, reference: np.ndarray,
               greyscale: bool, ctx: TextureContext, settings: DefaultSettings) -> np.ndarray:
    """(S, S) float32 in [0, 1]: how much of each covered texel is a highlight, from its de-lit
    luminance ``delit_lum`` (S, S) (shading and sheen out) against its neighbourhood's on the
    ``reference`` (S, S) bool texels (the reliably seen skin), and, on a spot narrower than
    ``settings.highlight_patch_mm``, from its whiteness (:func:`white_share` of the de-lit colour
    ``lin`` (S, S, 3) linear RGB / ``shading`` (S, S); a ``greyscale`` photo has no chroma to tell
    by: there the luminance alone); only where ``w`` (S, S) visibility > 0, feathered over S/512
    texels."""
    cover = ctx.coverage
    size = ctx.size
    lo, hi = settings.highlight_ratio
    ref_weight = reference
    # a seen texel with (almost) no reference skin within the neighbourhood's reach (an ear, the
    # neck, the scalp away from the face's reliable skin) is judged against the seen texels
    # around it: there the masked mean was 0 and the whole region passed for a highlight
    reach = gaussian_blur(ref_weight.astype(np.float32), size / 48.0) > settings.highlight_reference_support
    ref_weight = ref_weight | ((w > 0) & cover & ~reach)
    # by its luminance alone on a patch as wide as settings.highlight_patch_mm; on a narrower spot only as
    # far as it is whiter than its neighbourhood (a greyscale photo has no chroma to tell by)
    patch_lum = masked_blur(delit_lum, w > 0, settings.highlight_patch_mm / ctx.median_texel_mm)
    white = np.full(cover.shape, np.float32(greyscale))
    if not greyscale:  # (judged where a pass finds the texel bright enough: elsewhere it does not count)
        texture = lin / shading[..., None]
        colour = masked_blur(texture, ref_weight, size / 48.0)
        judged = np.zeros(cover.shape, bool)
        white_lo, white_hi = settings.highlight_white_share
    reach_texels = max(1, round(2.0 * settings.highlight_patch_mm / ctx.median_texel_mm))
    around = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach_texels + 1, 2 * reach_texels + 1))
    for _ in range(2):  # the neighbourhood's mean without the highlight candidates of the first pass
        ref_lum = np.maximum(masked_blur(delit_lum, ref_weight, size / 48.0), 1e-6)
        ratio = delit_lum / ref_lum
        if not greyscale:
            todo = (ratio > lo) & ~judged
            white[todo] = np.clip((white_share(texture[todo], colour[todo]) - white_lo) / (white_hi - white_lo), 0.0, 1.0)
            judged |= todo
        # a patch's evidence reaches over its rim (2σ), which the patch's blur makes darker
        patch = cv2.dilate(np.clip((patch_lum / ref_lum - lo) / (hi - lo), 0.0, 1.0).astype(np.float32), around)
        highlight = np.clip((ratio - lo) / (hi - lo), 0.0, 1.0) * np.maximum(patch, white) * (w > 0)
        ref_weight = ref_weight & (highlight == 0)
    return np.clip(gaussian_blur(highlight, max(1.0, size / 512.0)) * 2.0, 0.0, 1.0) * cover


def white_share(texture: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(...) float32 in [0, 1]: the share of each texel's luminance excess over ``reference``
    (..., 3) linear RGB (its neighbourhood's colour) that a white component explains, by the
    dichromatic model: ``texture`` (..., 3) linear RGB = k · reference + s · (1, 1, 1), k and s by
    least squares over the three channels; the share is s over (luminance(texture) −
    luminance(reference)) (0 where the texel is not brighter). A brighter skin colour gives 0, a
    specular reflection of a white light 1."""
    rr, rt = np.einsum("...k,...k->...", reference, reference), np.einsum("...k,...k->...", reference, texture)
    r1, t1 = channel_sum(reference), channel_sum(texture)
    s = (rr * t1 - r1 * rt) / np.maximum(3.0 * rr - r1 * r1, 1e-12)  # Cramer's rule on the 2 × 2 normal equations
    excess = np.maximum(luminance(texture) - luminance(reference), 1e-6)
    return np.clip(s / excess, 0.0, 1.0).astype(np.float32)
