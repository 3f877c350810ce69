"""How far each seen texel is trusted.

Every seen texel has a reliability r in [0, 1] (:func:`reliability`): its kept visibility × a
foreshortening ramp (``settings.foreshortening``) × a ramp over ``settings.edge_mm`` mm from the
nearest unseen texel (silhouettes, occluders, highlights), and in the fill × a ramp down where the
estimated shading is steep (:func:`shading_confidence`, ``settings.shading_error``): a shadow's
edge or a hard light's terminator that the fitted mesh misplaces by a few mm. The fill keeps a
seen texel by its reliability, so the seen skin fades into the fill instead of ending.
"""

from __future__ import annotations

import numpy as np

from facegeo.texturing.backend import TextureContext
from facegeo.texturing.default.settings import DefaultSettings
from facegeo.texturing.default.texels import smoothstep
from facegeo.texturing.image_filters import euclidean_distance

__all__ = ["inner_distance", "reliability", "shading_confidence"]


def inner_distance(seen: np.ndarray, ctx: TextureContext) -> np.ndarray:
    """(S, S) float32 distance in mm (texel distance × the median texel size) from each ``seen``
    (S, S) bool texel to the nearest covered texel that is not seen; texels outside the layout
    count as seen, so island borders are no boundary."""
    cover = ctx.coverage
    if not (seen & cover).any():
        return np.zeros(cover.shape, np.float32)
    return (euclidean_distance(seen | ~cover) * ctx.median_texel_mm).astype(np.float32)


def reliability(weight: np.ndarray, inner: np.ndarray, ctx: TextureContext, settings: DefaultSettings) -> np.ndarray:
    """(S, S) float32 in [0, 1]: how far each seen texel is trusted, the kept ``weight`` (S, S)
    (visibility × coverage × facing × (1 − occlusion) × (1 − highlight)) times a foreshortening
    ramp (camera-space normal z from ``settings.foreshortening`` [0] to [1]) times a ramp over
    ``settings.edge_mm`` mm of surface from the nearest texel not seen (``inner``:
    :func:`inner_distance` of ``weight > 0.5``, (S, S) mm); 0 where ``weight`` ≤ 0.5."""
    cover = ctx.coverage
    lo, hi = settings.foreshortening
    fore = smoothstep((ctx.normal_camera[..., 2] - lo) / (hi - lo))
    edge = inner / settings.edge_mm
    return np.where(cover & (weight > 0.5), np.clip(weight, 0.0, 1.0) * fore * smoothstep(edge), 0.0).astype(np.float32)


def shading_confidence(shading: np.ndarray, ctx: TextureContext, settings: DefaultSettings) -> np.ndarray:
    """(S, S) float32 in [0, 1]: 1 − a ramp of the de-lit log-albedo's error if the ``shading``
    (S, S) were misplaced on the surface by ``settings.shadow_softness_mm`` (its log's slope per mm
    times that), from ``settings.shading_error`` [0] to [1]; 1 where the shading is flat."""
    cover = ctx.coverage
    dy, dx = np.gradient(np.log(np.maximum(shading, 1e-6)))
    inside = cover.copy()  # central differences only between covered texels
    inside[1:-1, 1:-1] &= cover[2:, 1:-1] & cover[:-2, 1:-1] & cover[1:-1, 2:] & cover[1:-1, :-2]
    inside[[0, -1], :] = inside[:, [0, -1]] = False
    error = np.where(inside, np.hypot(dx, dy), 0.0) / ctx.median_texel_mm * settings.shadow_softness_mm
    lo, hi = settings.shading_error
    return (1.0 - smoothstep((error - lo) / (hi - lo))).astype(np.float32)
