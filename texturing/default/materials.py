"""Materials: the PBR maps from the homogenised texture (the albedo).

Albedo = the homogenised texture; displacement (mm) and the tangent-space normal from its
high-frequency log-luminance detail (above ~S · ``settings.detail_sigma_fraction`` texels⁻¹) at
``settings.detail_depth_mm`` mm per unit (± ``settings.detail_limit_mm``; dark = deeper);
occluders never reach it (they are filled before); roughness and specular from facial-region
priors (``settings.region_priors``) blurred to smooth anatomical shapes (σ = S/64 texels, ~8 mm)
and raised/lowered by the highlight evidence. Every map is padded outside the UV islands
(:func:`~facegeo.texturing.image_filters.pad_outside`, ``settings.pad_fraction``).
"""

from __future__ import annotations

import numpy as np

from facegeo.asset import MAP_NAMES
from facegeo.colour import luminance, srgb_to_linear
from facegeo.texturing.backend import TextureContext
from facegeo.texturing.default.settings import DefaultSettings
from facegeo.texturing.image_filters import masked_blur, pad_outside, pad_width

__all__ = ["materials", "normal_from_height", "region_priors"]


def materials(T_hom: np.ndarray, ctx: TextureContext, maps: frozenset[str] | set[str], highlight: np.ndarray | None,
              settings: DefaultSettings) -> dict[str, np.ndarray]:
    """PBR maps (see :mod:`facegeo.asset`; each (S, S[, 3]) float32, padded outside the layout) from the
    homogenised texture ``T_hom`` (S, S, 3) sRGB; only ``maps``. ``highlight`` (S, S) in [0, 1]:
    the analysis's highlights of this context (the glossier skin's evidence), or None."""
    unknown = set(maps) - set(MAP_NAMES)
    if unknown:
        raise ValueError(f"maps: expected a subset of {MAP_NAMES}, got {sorted(unknown)}")
    cover = ctx.coverage
    width = pad_width(ctx.size, settings.pad_fraction)

    def pad(map_: np.ndarray) -> np.ndarray:
        return pad_outside(map_, cover, width)

    out: dict[str, np.ndarray] = {}
    if "albedo" in maps:
        out["albedo"] = T_hom.astype(np.float32)
    if not {"normal", "displacement", "roughness", "specular"} & set(maps):
        return out
    if {"normal", "displacement"} & set(maps):
        log_l = np.log(np.maximum(luminance(srgb_to_linear(T_hom)), 1e-4))
        sigma = max(0.75, ctx.size * settings.detail_sigma_fraction)
        detail = np.where(cover, log_l - masked_blur(log_l, cover, sigma), 0.0).astype(np.float32)
        displacement = np.clip(settings.detail_depth_mm * detail, -settings.detail_limit_mm, settings.detail_limit_mm)  # dark = deeper
        if "displacement" in maps:
            out["displacement"] = pad(displacement.astype(np.float32))
        if "normal" in maps:
            out["normal"] = pad(normal_from_height(displacement, ctx))
    if {"roughness", "specular"} & set(maps):
        rough, spec = region_priors(ctx, settings)
        evidence = np.zeros(cover.shape, np.float32)
        if highlight is not None:
            evidence = np.clip(masked_blur(highlight, cover, ctx.size / 96.0) * 2.0, 0.0, 1.0)  # ~3 mm: no blobs
        if "roughness" in maps:  # where highlights were seen the skin is glossier: up to −35 % roughness
            out["roughness"] = pad(np.clip(rough * (1.0 - 0.35 * evidence), 0.05, 1.0).astype(np.float32))
        if "specular" in maps:  # and more specular: up to +50 %
            out["specular"] = pad(np.clip(spec * (1.0 + 0.5 * evidence), 0.0, 1.0).astype(np.float32))
    return out


def normal_from_height(height_mm: np.ndarray, ctx: TextureContext) -> np.ndarray:
    """Tangent-space normals (S, S, 3) in [−1, 1] of a height field in mm: n ∝ (−∂h/∂u,
    −∂h/∂v, 1) with the derivatives per mm on the surface (+u = columns, +v = rows up)."""
    dh_dcol = np.gradient(height_mm, axis=1)
    dh_drow = np.gradient(height_mm, axis=0)
    du = np.maximum(ctx.texel_size_mm[..., 0], 1e-3)
    dv = np.maximum(ctx.texel_size_mm[..., 1], 1e-3)
    n = np.stack([-dh_dcol / du, dh_drow / dv, np.ones_like(height_mm)], axis=-1)
    length = np.sqrt(n[..., 0] * n[..., 0] + n[..., 1] * n[..., 1] + n[..., 2] * n[..., 2])  # np.linalg.norm's sum, bit for bit,
    return (n / length[..., None]).astype(np.float32)  # without its slow reduction over a length-3 axis


def region_priors(ctx: TextureContext, settings: DefaultSettings) -> tuple[np.ndarray, np.ndarray]:
    """Region-weighted (roughness, specular) priors (``settings.region_priors``, elsewhere
    ``settings.default_prior``), (S, S) float32 each, blurred over S/64 texels
    (~8 mm at 1K) so region borders are smooth anatomical gradients, not landmark discs."""
    cover = ctx.coverage
    shape = cover.shape
    total = np.zeros(shape, np.float32)
    rough = np.zeros(shape, np.float32)
    spec = np.zeros(shape, np.float32)
    for name, (r, s) in settings.region_priors:
        if name in ctx.regions:
            w = ctx.regions[name].astype(np.float32)
            total += w
            rough += w * r
            spec += w * s
    rest = np.clip(1.0 - total, 0.0, 1.0)
    norm = np.maximum(total + rest, 1e-6)
    rough = (rough + rest * settings.default_prior[0]) / norm
    spec = (spec + rest * settings.default_prior[1]) / norm
    sigma = ctx.size / 64.0
    return masked_blur(rough, cover, sigma), masked_blur(spec, cover, sigma)
