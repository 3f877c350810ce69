"""A directional light and its cast shadows, fitted to the seen skin.

Where the SH fit's de-lighting strength is above 0 and the context has the posed mesh, the SH
shading is replaced by a physical model fitted to the same skin, luminance ≈ albedo · (ambient +
L · max(n·l, 0) · V_l) (:func:`directional_shading`), V_l the texel's visibility from the light
by a shadow map of the posed mesh (:func:`facegeo.uv.light_visibility`: the nose's, brow's and
jaw's cast shadows), blurred over ``settings.shadow_softness_mm``; dips are then looked for only
within ~``settings.shadow_edge_mm`` of a cast shadow's edge (which the fitted mesh misplaces by a
few mm; elsewhere what is left is albedo, a beard), and the gains are bounded by
``settings.light_gain`` (a hard light's shadowed side is 5–15× darker).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from facegeo.texturing.backend import TextureContext
from facegeo.texturing.default.settings import DefaultSettings
from facegeo.texturing.default.texels import subsample
from facegeo.texturing.image_filters import masked_blur
from facegeo.uv.renderer import light_visibility, sphere_directions

__all__ = ["directional_shading"]


def directional_shading(lum: np.ndarray, fit_mask: np.ndarray, ctx: TextureContext,
                        settings: DefaultSettings) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """The shading (S, S) float32 of one directional light and an ambient term fitted to the
    reliably seen skin's luminance ``lum`` (S, S) linear on ``fit_mask`` (S, S) bool:
    lum ≈ albedo · (ambient + L · max(n·l, 0) · V_l), n the camera-space normal, V_l the
    texel's visibility from the light (a shadow map of the posed mesh, blurred over
    ``settings.shadow_softness_mm``), the albedo taken as constant (robust: soft-L1 loss on the
    log-ratio). l: the best of ``settings.light_candidates`` directions (least squares for ambient
    and L, median |log-ratio|), refined with V_l of that direction, then V_l recomputed.
    Also the cast shadows' own factor (S, S) float32, the shading over that without V_l (1 where
    nothing is in shadow, flat across the terminator), and a JSON-ready report (direction,
    ambient / L, and the ambient term in ``lum``'s units)."""
    from scipy.optimize import least_squares  # here only: 0.3 s of import that an even light never needs

    cover = ctx.coverage
    rows = subsample(np.flatnonzero(fit_mask.ravel()), settings.light_fit_texels)
    n = ctx.normal_camera.reshape(-1, 3)[rows].astype(np.float64)
    log_y = np.log(np.maximum(lum.ravel()[rows].astype(np.float64), 1e-6))
    y = np.exp(log_y)
    # the grid: per candidate direction, ambient and L by least squares, scored by the median |log-ratio|
    candidates = sphere_directions(settings.light_candidates)
    candidates = candidates[(candidates[:, 2] >= settings.light_min_z) & (candidates[:, 1] >= settings.light_min_y)]
    grid_rows = slice(None, None, max(1, len(rows) // 4000))
    cos = np.maximum(n[grid_rows] @ candidates.T, 0.0)  # (n, K)
    yg = y[grid_rows, None]
    c_mean, y_mean = cos.mean(axis=0), yg.mean()
    gain = np.maximum(((cos - c_mean) * (yg - y_mean)).mean(axis=0) / np.maximum(cos.var(axis=0), 1e-12), 0.0)
    ambient = np.maximum(y_mean - gain * c_mean, 1e-3 * y_mean)
    score = np.median(np.abs(np.log(yg / (ambient + gain * cos))), axis=0)
    best = int(np.argmin(score))

    def direction(angles: np.ndarray) -> np.ndarray:
        return np.array([np.sin(angles[0]) * np.cos(angles[1]), np.sin(angles[0]) * np.sin(angles[1]), np.cos(angles[0])])

    def visible(light: np.ndarray) -> np.ndarray:
        flat = np.flatnonzero(cover.ravel())
        lit = np.ones(cover.size, np.float32)
        lit[flat] = light_visibility(ctx.vertices_camera, ctx.triangles, ctx.position_camera.reshape(-1, 3)[flat], light,
                                     settings.shadow_map_mm)
        lit = lit.reshape(cover.shape)
        return np.where(cover, masked_blur(lit, cover, settings.shadow_softness_mm / ctx.median_texel_mm), 1.0)

    def residual(x: np.ndarray, v: np.ndarray) -> np.ndarray:
        return log_y - np.log(np.exp(x[2]) + np.exp(x[3]) * np.maximum(n @ direction(x[:2]), 0.0) * v)

    l0 = candidates[best]
    x = np.array([np.arccos(np.clip(l0[2], -1, 1)), np.arctan2(l0[1], l0[0]), np.log(ambient[best]), np.log(max(gain[best], 1e-6))])
    v = visible(l0)
    start = x
    x = least_squares(residual, start, args=(v.ravel()[rows],), loss="soft_l1", f_scale=0.1, max_nfev=100).x
    if direction(x[:2])[1] < settings.light_min_y:  # refined to below the lowest light: the grid's direction kept
        x = np.concatenate([start[:2], least_squares(lambda rest, v: residual(np.concatenate([start[:2], rest]), v), start[2:],
                                                     args=(v.ravel()[rows],), loss="soft_l1", f_scale=0.1, max_nfev=100).x])
    light = direction(x[:2])
    v = visible(light)
    direct = np.exp(x[3]) * np.maximum(ctx.normal_camera @ light, 0.0)
    shading = np.exp(x[2]) + direct * v
    cast = shading / (np.exp(x[2]) + direct)
    report = {"direction": [float(c) for c in light], "ambient_over_light": float(np.exp(x[2] - x[3])),
              "ambient": float(np.exp(x[2])), "lit_fraction_of_fit": float((v[fit_mask] > 0.5).mean())}
    return np.where(cover, shading, 1.0).astype(np.float32), np.where(cover, cast, 1.0).astype(np.float32), report
