"""De-lighting: the shading of the photo's light per texel, fitted to the reliably seen skin.

Every step works on linear RGB; the shading is one scalar per texel (luminance only).

* **Shading** (:func:`analyse`): order-1 spherical harmonics (``settings.sh_terms``) of the
  camera-space normal are fitted to the luminance of the reliably seen skin
  (:func:`~facegeo.texturing.default.reliability.reliability` > 0.5; iteratively trimmed least
  squares: texels whose log-ratio to the fit is beyond 2.5 robust σ, highlights, creases, stray
  occluders, are left out) and applied as shading^strength, the strength rising with how
  directional the fitted light is (``settings.directional_range``) or how far its irradiance would
  vary over the whole sphere of normals (``settings.contrast_range``: a hard light whose shadowed
  side the skin mask left out shows little variation over the lit skin that is kept, but a steep
  one): under an even light the fit finds only albedo that correlates with the normals and leaves
  it alone. Where the strength is above 0 and the context has the posed mesh, a directional light
  with its cast shadows replaces the SH shading
  (:mod:`~facegeo.texturing.default.directional_light`); what else it changes (the dips below, the
  gains' bounds, the environment's sheen) weighs by the strength, so that a photo just over the
  threshold is de-lit as one just under it.
* **Cast shadows and occlusion** that SH cannot explain (:func:`shadow_dips`): dips of the de-lit
  log-luminance at ~S/128 texels below the brighter of its ~S/12 and ~S/5 neighbourhoods (~25 and
  ~60 mm; broad shadows such as the jaw's on the neck), deeper than ``settings.shadow_tolerance``;
  under the directional light only within ~``settings.shadow_edge_mm`` of a cast shadow's edge;
  under an even light, where the context has the posed mesh, no deeper than its occlusion allows:
  the log of its sky visibility (:func:`facegeo.uv.sky_visibility`, the irradiance an even
  environment leaves a texel) at its lowest within ``settings.shadow_edge_mm``
  (:func:`occlusion_floor`: the nostrils, the eyes' and mouth's corners; on open skin a dip is
  albedo, a beard).
* **Gains**: the de-lighting gain 1/shading is bounded to [1/g, g] with g = ``settings.max_gain``
  where the surface faces the camera, falling to ``settings.grazing_gain`` at grazing angles (SH
  fits underestimate grazing irradiance; unbounded gains made metallic streaks); under the
  directional light ``settings.light_gain``.

:func:`analyse` then takes the skin's sheen out (:mod:`~facegeo.texturing.default.sheen`), finds
the highlights (:mod:`~facegeo.texturing.default.highlights`), the clipped texels
(:mod:`~facegeo.texturing.default.clipping`) and an occluder's fringe
(:mod:`~facegeo.texturing.default.occluders`), and gives what is kept of each texel as seen.

The context's fitted SH lighting (``ctx.gamma``) is not used: it is fitted per RGB channel to the
model's albedo, and dividing by it put its colour errors into the albedo (casts).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from facegeo.colour import channel_max, channel_min, is_greyscale, luminance
from facegeo.lighting import sh_basis
from facegeo.texturing.backend import TextureContext
from facegeo.texturing.default.clipping import clipped_ceiling
from facegeo.texturing.default.directional_light import directional_shading
from facegeo.texturing.default.highlights import highlights
from facegeo.texturing.default.occluders import grey_fringe, occluder_fringe
from facegeo.texturing.default.reliability import inner_distance, reliability, shading_confidence
from facegeo.texturing.default.settings import DefaultSettings
from facegeo.texturing.default.sheen import environment_specular, sun_lobe, without_specular
from facegeo.texturing.default.texels import skin_texels, smoothstep, subsample
from facegeo.texturing.image_filters import gaussian_blur, masked_blur
from facegeo.uv.renderer import sky_visibility

__all__ = ["Analysis", "analyse", "occlusion_floor", "shadow_dips"]


@dataclass
class Analysis:
    """Per-texel results of :func:`analyse` (all (S, S) float32)."""

    shading: np.ndarray
    highlight: np.ndarray
    weight: np.ndarray  # visibility × (1 − highlight): how much of each texel is kept as seen
    specular: np.ndarray  # the skin's specular reflection in de-lit units (white after the light's colour is removed)
    greyscale: bool  # the seen texels are grey (:func:`facegeo.colour.is_greyscale`)
    # under the directional light model: how much of a de-lit texel's log is the ambient term's,
    # strength × ambient / shading (the shading is applied as shading^strength); else None
    ambient_dependence: np.ndarray | None
    # under the directional light model: how much of the light's sheen a texel may show, in [0, 1]
    # (:func:`~facegeo.texturing.default.sheen.sun_lobe`); else None
    sun_lobe: np.ndarray | None


def analyse(T_inc: np.ndarray, lin: np.ndarray, M_vis: np.ndarray, ctx: TextureContext, constants: Mapping[str, float],
            settings: DefaultSettings) -> tuple[Analysis, dict[str, Any] | None, dict[str, Any]]:
    """Shading, highlights and kept weight of the photo texture ``T_inc`` (S, S, 3) sRGB, already
    linearised as ``lin`` (S, S, 3) float32 linear RGB with its clipped channels restored
    (:func:`~facegeo.texturing.default.clipping.restore_clipped`), seen with visibility ``M_vis`` (S, S) in
    [0, 1] (module docstring); ``constants``: the backend's roughness and specular of generic
    skin (the sheen's GGX). Returns the :class:`Analysis`, the directional light model's report
    (direction, ambient; None where the model is not used) and the analysis's statistics (the
    backend's ``report["analyse"]``)."""
    cover = ctx.coverage
    w = np.clip(M_vis, 0.0, 1.0).astype(np.float32) * cover
    lum = luminance(lin)
    # the fit trusts only reliable skin: facing the camera, away from silhouettes and occluders
    # (at a silhouette the photo mixes in the background: a white wall made grazing skin "lit")
    inner = inner_distance(w > 0.5, ctx)
    # (``lin`` has its clipped channels restored, never lowered: a texel with some channel at the
    # ceiling was clipped; one with all three could not be restored and is a lower bound only)
    ceiling = clipped_ceiling(settings)
    clipped = (channel_max(lin)[..., 0] >= ceiling) & cover
    fit_mask = skin_texels(ctx) & (reliability(w, inner, ctx, settings) > 0.5) & (lum > 1e-4) & ~(clipped & (channel_min(lin) >= ceiling))
    normals = ctx.normal_camera
    shading = np.ones(cover.shape, np.float32)
    n_fit = int(fit_mask.sum())
    directional = strength = contrast = 0.0
    light: dict[str, Any] | None = None  # the directional light model's report, where it is used
    ambient_share: np.ndarray | None = None  # under the directional model: ambient / shading, per texel
    lobe: np.ndarray | None = None
    if n_fit >= 100:
        coeffs, directional, contrast, strength = _sh_fit(lum, fit_mask, normals, settings)
        if strength > 0 and ctx.vertices_camera is not None and ctx.position_camera is not None and ctx.triangles is not None:
            e, cast, light = directional_shading(lum, fit_mask, ctx, settings)
            ambient_share = np.clip(light["ambient"] / np.maximum(e, 1e-12), 0.0, 1.0)
            lobe = sun_lobe(np.asarray(light["direction"]), strength * (1.0 - ambient_share), ctx, settings)
        else:  # the SH fit's own shading over the layout
            cast = None
            flat = np.flatnonzero(cover.ravel())
            e = np.zeros(cover.size)
            e[flat] = sh_basis(normals.reshape(-1, 3)[flat].astype(np.float32))[:, :settings.sh_terms] @ coeffs
            e = e.reshape(cover.shape)
        ref = float(np.median(e[fit_mask]))
        shading = np.where(cover, np.maximum(e / max(ref, 1e-6), 1e-3) ** strength, 1.0).astype(np.float32)
        dips = shadow_dips(lum, shading, fit_mask, cast, ctx, settings)
        if cast is not None and strength < 1.0:  # the light model's dips weigh by its strength (continuous at 0)
            dips = strength * dips + (1.0 - strength) * shadow_dips(lum, shading, fit_mask, None, ctx, settings)
        shading = shading * np.exp(np.where(cover, dips, 0.0))
    facing = np.clip(normals[..., 2] / 0.5, 0.0, 1.0)
    grazing, most = settings.grazing_gain, settings.max_gain
    if light is not None:  # the light model's bounds, geometrically by its strength (its own at 1, the SH fit's at 0)
        grazing = grazing ** (1.0 - strength) * settings.light_gain[0] ** strength
        most = most ** (1.0 - strength) * settings.light_gain[1] ** strength
    bound = grazing + (most - grazing) * facing
    shading = np.where(cover, np.clip(shading, 1.0 / bound, bound), 1.0).astype(np.float32)
    delit_lum = lum / shading
    # under the light model only its ambient part reflects the even environment, by its strength
    env_share = None if ambient_share is None else ambient_share + (1.0 - strength) * (1.0 - ambient_share)
    specular = environment_specular(delit_lum, fit_mask if n_fit else (w > 0), w > 0, ctx, env_share, constants, settings)
    specular_share = float(specular[fit_mask].sum() / max(float(delit_lum[fit_mask].sum()), 1e-12)) if n_fit else 0.0
    delit_lum = without_specular(delit_lum, specular, settings)
    seen = (w > 0.5) & cover
    seen_skin = seen & skin_texels(ctx)
    greyscale = bool(seen.any()) and is_greyscale(T_inc[seen])
    highlight = highlights(delit_lum, lin, shading, w, fit_mask if n_fit else cover, greyscale, ctx, settings)
    kept = w * (1.0 - highlight)
    # without chroma a dark sideburn or hairline passes the photo's skin mask anywhere on the face
    fringe = occluder_fringe(lin, shading, w, inner, fit_mask, ctx, np.inf if greyscale else settings.fringe_mm,
                             settings) if n_fit >= 100 else None
    if fringe is not None and greyscale:  # and its step in luminance from the skin beside it, at the
        # edge of what is kept so far
        kept_inner = inner_distance(w * (1.0 - fringe) > 0.5, ctx)
        fringe = np.maximum(fringe, grey_fringe(lin, shading, w, kept_inner, fit_mask & (fringe < 0.5), ctx, settings))
    if fringe is not None:
        kept = kept * (1.0 - fringe)
    analysis = Analysis(shading, highlight.astype(np.float32), kept.astype(np.float32), specular, greyscale,
                        None if ambient_share is None else (strength * ambient_share).astype(np.float32), lobe)
    statistics = {
        "fit_texels": n_fit,
        "directional": directional,
        "irradiance_contrast": contrast,
        "delighting_strength": strength,
        "gain_p05_p95": [float(x) for x in np.percentile(1.0 / shading[fit_mask], [5, 95])] if n_fit else [1.0, 1.0],
        "highlight_fraction_of_seen_skin": float(highlight[fit_mask].mean()) if n_fit else 0.0,
        "clipped_fraction_of_seen_skin": float(clipped[seen_skin].mean()) if seen_skin.any() else 0.0,
        "specular_fraction_of_seen_skin": specular_share,
        "occluder_fringe_fraction_of_seen_skin": float(fringe[seen_skin].mean()) if fringe is not None else 0.0,
    }
    return analysis, light, statistics


def _sh_fit(lum: np.ndarray, fit_mask: np.ndarray, normals: np.ndarray,
            settings: DefaultSettings) -> tuple[np.ndarray, float, float, float]:
    """The SH shading fitted to the luminance ``lum`` (S, S) linear of the ``fit_mask`` (S, S)
    bool texels with camera-space ``normals`` (S, S, 3): its coefficients (``settings.sh_terms``,)
    float64 of :func:`facegeo.lighting.sh_basis`, how directional it is (the std of its linear
    part over its mean), its irradiance contrast κ over the sphere of normals, and the
    de-lighting strength in [0, 1] these give (``settings.directional_range``,
    ``settings.contrast_range``)."""
    rows = subsample(np.flatnonzero(fit_mask.ravel()))
    basis = sh_basis(normals.reshape(-1, 3)[rows].astype(np.float32)).astype(np.float64)[:, :settings.sh_terms]
    y = lum.ravel()[rows].astype(np.float64)
    keep = np.ones(len(rows), bool)
    for _ in range(4):  # trimmed least squares on the log-ratio
        coeffs, *_ = np.linalg.lstsq(basis[keep], y[keep], rcond=None)
        r = np.log(y / np.maximum(basis @ coeffs, 1e-6))
        med = np.median(r[keep])
        keep = np.abs(r - med) < 2.5 * 1.4826 * np.median(np.abs(r[keep] - med)) + 1e-6
    # how directional the fitted light is: under an even light the fit only finds albedo that
    # happens to correlate with the normals, and dividing by it would put that into the albedo
    directional = float(np.std(basis[keep][:, 1:4] @ coeffs[1:4]) / max(float(np.mean(basis[keep] @ coeffs)), 1e-12))
    # the Deep3D basis: constant term 0.886·c0, linear terms 1.772·(c·n), so κ = 2|c_1..3| / c0
    linear = 2.0 * float(np.linalg.norm(coeffs[1:4]))
    contrast = linear / coeffs[0] if coeffs[0] > linear / settings.contrast_cap else settings.contrast_cap
    d_lo, d_hi = settings.directional_range
    c_lo, c_hi = settings.contrast_range
    strength = float(max(smoothstep(np.float32((directional - d_lo) / (d_hi - d_lo))),
                         smoothstep(np.float32((contrast - c_lo) / (c_hi - c_lo)))))
    return coeffs, directional, contrast, strength


def shadow_dips(lum: np.ndarray, shading: np.ndarray, fit_mask: np.ndarray, cast: np.ndarray | None, ctx: TextureContext,
                settings: DefaultSettings) -> np.ndarray:
    """(S, S) float32 ≤ 0, the log of the shading's factor for the cast shadows and occlusion that
    ``shading`` (S, S) does not explain: local dips of the de-lit log-luminance (``lum`` (S, S)
    linear / ``shading``) below the neighbourhood, deeper than ``settings.shadow_tolerance``, where
    the ``fit_mask`` (S, S) bool skin gives evidence; with the directional light model's ``cast``
    shadows (S, S; its factor, :func:`~facegeo.texturing.default.directional_light.directional_shading`)
    only within ~``settings.shadow_edge_mm`` of their edges, without it no deeper than the posed
    mesh's occlusion (:func:`occlusion_floor`, where the context has the mesh)."""
    size = ctx.size
    log_a = np.log(np.maximum(lum / shading, 1e-4))
    local = masked_blur(log_a, fit_mask, size / 128.0)
    region = np.maximum(masked_blur(log_a, fit_mask, size / 12.0), masked_blur(log_a, fit_mask, size / 5.0))
    support = np.clip(gaussian_blur(fit_mask, size / 128.0) * 2.0, 0.0, 1.0)
    dip = np.clip(local - region + settings.shadow_tolerance, -0.7, 0.0) * support  # no evidence, no shadow
    if cast is not None:  # the light model has its cast shadows: a dip far from their edges is albedo (a
        # beard), one near an edge the shadow that the fitted mesh put a few mm off
        steep = 1.0 - shading_confidence(cast, ctx, settings)
        dip = dip * np.clip(gaussian_blur(steep, settings.shadow_edge_mm / ctx.median_texel_mm) * 3.0, 0.0, 1.0)
    elif ctx.surface is not None and ctx.vertices_camera is not None and ctx.triangles is not None:
        # under an even light a dip is occlusion only as deep as the fitted mesh's sky
        # visibility allows within settings.shadow_edge_mm (the nostrils, the eyes' corners); deeper,
        # or on open skin, it is albedo (a beard)
        dip = np.maximum(dip, occlusion_floor(ctx, dip < 0, settings))
    return dip


def occlusion_floor(ctx: TextureContext, dips: np.ndarray, settings: DefaultSettings) -> np.ndarray:
    """(S, S) float32 ≤ 0: the log of the posed mesh's sky visibility
    (:func:`facegeo.uv.sky_visibility`, the irradiance an even environment leaves it) at its
    lowest within ``settings.shadow_edge_mm`` of each texel (the fitted mesh is a few mm off),
    evaluated at the vertices within that distance of the ``dips`` (S, S) bool texels only (0
    elsewhere: no dip there to bound); 0 outside the layout."""
    cover = ctx.coverage
    radius = max(1, int(round(settings.shadow_edge_mm / ctx.median_texel_mm)))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    near = cv2.dilate((dips & cover).astype(np.uint8), disc).astype(bool) & cover
    _, touched = ctx.surface.to_vertices(near.astype(np.float32), near.astype(np.float32))
    at = np.flatnonzero(touched > 0)
    sky = np.ones(len(touched), np.float32)
    sky[at] = sky_visibility(ctx.vertices_camera, ctx.triangles, at=at)
    lowest = cv2.erode(np.where(cover, ctx.surface.to_texels(sky[:, None], ctx.size)[..., 0], 1.0).astype(np.float32), disc)
    return np.where(cover, np.log(np.maximum(lowest, 1e-3)), 0.0).astype(np.float32)
