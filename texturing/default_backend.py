"""The weight-free, deterministic default texture backend.

Every heuristic is stated in one line where it lives. Colour textures are sRGB in [0, 1],
float32, S × S, image-style rows (see :mod:`facegeo.texturing.backend`).

* inpaint: mirror texels (facial left/right symmetry in UV) fill what the photo does not see;
  what neither side sees comes from the model's texture after a Lab colour transfer to the
  visible skin; the two are joined by Laplacian-pyramid (multi-band) blending so no seam shows.
* homogenise: divide out the fitted SH irradiance (normalised to mean 1 on the skin), then the
  part of the remaining low-frequency log-luminance that is still explained by the SH basis of
  the normals (residual shading the fit missed); chroma is kept.
* materials: albedo = homogenised texture; displacement (mm) and tangent-space normal from its
  high-frequency log-luminance detail; roughness and specular from facial-region priors
  modulated by the detail.
* upscale: Lanczos (OpenCV ``INTER_LANCZOS4``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import torch
from scipy import ndimage

from facegeo.asset import MAP_NAMES
from facegeo.colour import linear_to_srgb, luminance, srgb_to_linear
from facegeo.lighting import sh_basis, sh_irradiance
from facegeo.texturing.backend import TextureContext

__all__ = ["DefaultBackend", "REGION_PRIORS", "pad_outside", "masked_blur", "multiband_blend"]

#: (roughness, specular) priors per facial region; oily T-zone glossier, brows matte, lips smooth
#: and less specular (values in the range of measured facial BRDF fits, e.g. Weyrich et al. 2006).
REGION_PRIORS: dict[str, tuple[float, float]] = {
    "forehead": (0.45, 0.60),
    "nose": (0.40, 0.65),
    "cheeks": (0.55, 0.45),
    "chin": (0.50, 0.50),
    "lips": (0.35, 0.40),
    "brows": (0.75, 0.25),
    "eyes": (0.30, 0.70),
}
#: Roughness and specular where no region mask says otherwise (skin on the head and neck).
DEFAULT_PRIOR = (0.55, 0.45)


def masked_blur(image: np.ndarray, weight: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur of ``image`` (S, S[, C]) that only averages texels with ``weight`` (S, S) >
    0: blur(w·x) / blur(w). Texels with no weighted neighbour within ~3σ get 0."""
    w = weight.astype(np.float32)
    num = cv2.GaussianBlur(image * (w[..., None] if image.ndim == 3 else w), (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    den = cv2.GaussianBlur(w, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    den = np.maximum(den, 1e-6)
    return num / (den[..., None] if image.ndim == 3 else den)


def pad_outside(image: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Give every texel outside ``inside`` (S, S) bool the value of the nearest inside texel
    (seam padding: bilinear sampling and mip-maps never see the background)."""
    if inside.all() or not inside.any():
        return image
    _, (rows, cols) = ndimage.distance_transform_edt(~inside, return_indices=True)
    return image[rows, cols]


def multiband_blend(a: np.ndarray, b: np.ndarray, mask: np.ndarray, levels: int) -> np.ndarray:
    """Laplacian-pyramid blend of ``a`` where ``mask`` → 1 and ``b`` where it → 0 (Burt &
    Adelson 1983): each frequency band is mixed with a mask blurred to that band's scale."""
    levels = max(1, levels)
    m = mask.astype(np.float32)[..., None]
    ga, gb, gm = [a.astype(np.float32)], [b.astype(np.float32)], [m]
    for _ in range(levels - 1):
        ga.append(cv2.pyrDown(ga[-1]))
        gb.append(cv2.pyrDown(gb[-1]))
        gm.append(cv2.pyrDown(gm[-1])[..., None] if gm[-1].shape[-1] == 1 else cv2.pyrDown(gm[-1]))
    out = gm[-1] * ga[-1] + (1 - gm[-1]) * gb[-1]
    for k in range(levels - 2, -1, -1):
        size = (ga[k].shape[1], ga[k].shape[0])
        la = ga[k] - cv2.pyrUp(ga[k + 1], dstsize=size)
        lb = gb[k] - cv2.pyrUp(gb[k + 1], dstsize=size)
        band = gm[k] * la + (1 - gm[k]) * lb
        out = cv2.pyrUp(out, dstsize=size) + band
    return out


def _subsample(rows: np.ndarray, limit: int = 65536) -> np.ndarray:
    """At most ``limit`` evenly spaced entries of ``rows`` (least-squares fits of 9 SH
    coefficients need no more)."""
    return rows if len(rows) <= limit else rows[:: int(np.ceil(len(rows) / limit))]


def _weighted_stats(lab: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel weighted mean and standard deviation of an (S, S, 3) image."""
    w = weight.astype(np.float64)[..., None]
    total = max(float(w.sum()), 1e-9)
    mean = (lab * w).reshape(-1, 3).sum(0) / total
    return mean, np.sqrt(((lab - mean) ** 2 * w).reshape(-1, 3).sum(0) / total)


def _lab_transfer(source: np.ndarray, source_weight: np.ndarray, target_srgb: np.ndarray, target_weight: np.ndarray) -> np.ndarray:
    """Reinhard colour transfer in CIELAB: shift/scale ``source`` (S, S, 3) sRGB so its mean and
    standard deviation over ``source_weight`` match those of ``target_srgb`` over
    ``target_weight`` (both (S, S) weights; e.g. the layout and the visible skin)."""
    src = cv2.cvtColor(source.astype(np.float32), cv2.COLOR_RGB2Lab)
    tgt = cv2.cvtColor(target_srgb.astype(np.float32), cv2.COLOR_RGB2Lab)
    mean_t, std_t = _weighted_stats(tgt, target_weight)
    mean_s, std_s = _weighted_stats(src, source_weight)
    gain = np.where(std_s > 1e-3, std_t / np.maximum(std_s, 1e-3), 0.0)  # a flat source stays flat
    out = (src - mean_s) * gain + mean_t
    return np.clip(cv2.cvtColor(out.astype(np.float32), cv2.COLOR_Lab2RGB), 0.0, 1.0)


@dataclass
class DefaultBackend:
    """Weight-free texture backend; knobs are the blending ``levels`` (0: from the size) and the
    detail scale. ``report`` holds statistics of the last calls (e.g. remaining shading)."""

    name: str = "default"
    levels: int = 0
    detail_sigma_fraction: float = 1.0 / 512.0  # detail = frequencies above ~S/512 texels⁻¹ (pores, fine wrinkles)
    displacement_gain_mm: float = 0.5  # mm of depth per unit of log-luminance detail (dark = deeper)
    report: dict[str, Any] = field(default_factory=dict)
    _shading_cache: tuple[TextureContext, np.ndarray] | None = field(default=None, repr=False)

    # ---------------------------------------------------------------------------------- shading
    def shading(self, ctx: TextureContext) -> np.ndarray:
        """(S, S, 3) the fitted SH irradiance of each texel's normal divided by its mean over the
        skin, clipped to [0.5, 2]; 1 outside the layout. Computed once per context. The clip:
        SH fits to photos underestimate grazing irradiance (measured: with [0.25, 4], 12 % of
        the astronaut's skin texels sat at the ×4 floor and looked metallic)."""
        if self._shading_cache is not None and self._shading_cache[0] is ctx:
            return self._shading_cache[1]
        cover = ctx.coverage
        skin = cover if ctx.skin is None else cover & (ctx.skin > 0.5)
        irradiance = np.ones((*cover.shape, 3), np.float32)
        normals = torch.from_numpy(ctx.normal_camera[cover].astype(np.float32))
        irradiance[cover] = sh_irradiance(normals, torch.from_numpy(ctx.gamma.astype(np.float32))).numpy()
        mean_e = irradiance[skin].mean(axis=0) if skin.any() else np.ones(3, np.float32)
        shading = np.where(cover[..., None], np.clip(irradiance / np.maximum(mean_e, 1e-6), 0.5, 2.0), 1.0)
        self._shading_cache = (ctx, shading.astype(np.float32))
        return self._shading_cache[1]

    # ---------------------------------------------------------------------------------- inpaint
    def inpaint(self, T_inc: np.ndarray, M_vis: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S, 3) sRGB + (S, S) visibility -> (S, S, 3) sRGB, every texel filled, under the
        fitted lighting. The filling happens on the de-lit texture (each texel divided by the
        shading of its own normal), so a mirror texel brings its colour, not its lighting."""
        cover = ctx.coverage
        shading = self.shading(ctx)
        delit = linear_to_srgb(srgb_to_linear(T_inc) / shading)
        w = np.clip(M_vis, 0.0, 1.0).astype(np.float32) * cover
        has = (ctx.mirror[..., 0] >= 0) & cover
        rows, cols = np.where(has, ctx.mirror[..., 0], 0), np.where(has, ctx.mirror[..., 1], 0)
        w_m = np.where(has, w[rows, cols], 0.0)
        t_m = delit[rows, cols]
        confidence = w + (1 - w) * w_m  # seen directly, else through the mirror texel
        fill = (w[..., None] * delit + ((1 - w) * w_m)[..., None] * t_m) / np.maximum(confidence, 1e-6)[..., None]
        skin = cover if ctx.skin is None else cover * (ctx.skin > 0.5)
        base = _lab_transfer(ctx.mean_texture, skin, delit, w * skin)
        fill = np.where(confidence[..., None] > 1e-6, fill, base)
        levels = self.levels or max(1, int(np.log2(ctx.size)) - 3)  # bands down to ~8 texels
        blended = multiband_blend(fill, base, confidence, levels)
        # multi-band blending hides the seam but also pulls the model's coarse bands into what the
        # photo saw; keep the seen texels as seen (confidence 1) and blend only towards the holes
        out = np.clip(confidence[..., None] * fill + (1 - confidence[..., None]) * blended, 0.0, 1.0)
        self.report["inpaint"] = {
            "seen": float(w[cover].mean()),
            "seen_or_mirrored": float(confidence[cover].mean()),
            "levels": levels,
        }
        relit = linear_to_srgb(srgb_to_linear(out) * shading)
        return pad_outside(relit.astype(np.float32), cover)

    # ---------------------------------------------------------------------------------- homogenise
    def homogenise(self, T_full: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S, 3) sRGB -> (S, S, 3) sRGB under uniform white light."""
        cover = ctx.coverage
        skin = cover if ctx.skin is None else cover & (ctx.skin > 0.5)
        linear = srgb_to_linear(T_full)
        before = self._shading_variance(linear, ctx.normal_camera, skin)
        delit = linear / self.shading(ctx)
        # residual: the low-frequency log-luminance that the SH basis of the normals still explains
        log_l = np.log(np.maximum(luminance(delit), 1e-4))
        low = masked_blur(log_l, skin, sigma=ctx.size / 64.0)  # shading is smooth at ≥ S/64 texels
        fit_rows = _subsample(np.flatnonzero(skin.ravel()))
        flat_normals = ctx.normal_camera.reshape(-1, 3)
        basis = sh_basis(torch.from_numpy(flat_normals[fit_rows].astype(np.float32))).numpy()
        coeffs, *_ = np.linalg.lstsq(basis, low.ravel()[fit_rows] - low.ravel()[fit_rows].mean(), rcond=None)
        residual = np.zeros(cover.size, np.float32)
        residual[cover.ravel()] = sh_basis(torch.from_numpy(flat_normals[cover.ravel()].astype(np.float32))).numpy() @ coeffs
        residual = residual.reshape(cover.shape)
        residual -= residual[skin].mean()
        delit = delit * np.exp(-np.clip(residual, -0.7, 0.7))[..., None]  # at most a factor 2 either way
        after = self._shading_variance(delit, ctx.normal_camera, skin)
        self.report["homogenise"] = {
            "shading_variance_before": before,
            "shading_variance_after": after,
            "remaining_fraction": after / max(before, 1e-12),
        }
        return pad_outside(linear_to_srgb(np.where(cover[..., None], delit, linear)), cover)

    @staticmethod
    def _shading_variance(linear: np.ndarray, normals: np.ndarray, skin: np.ndarray) -> float:
        """Variance of the skin's log-luminance explained by the SH basis of the normals."""
        rows = _subsample(np.flatnonzero(skin.ravel()))
        log_l = np.log(np.maximum(luminance(linear.reshape(-1, 3)[rows]), 1e-4))
        basis = sh_basis(torch.from_numpy(normals.reshape(-1, 3)[rows].astype(np.float32))).numpy()
        coeffs, *_ = np.linalg.lstsq(basis, log_l - log_l.mean(), rcond=None)
        return float(np.var(basis @ coeffs))

    # ---------------------------------------------------------------------------------- materials
    def materials(self, T_hom: np.ndarray, ctx: TextureContext, maps: frozenset[str] | set[str] = frozenset(MAP_NAMES)) -> dict[str, np.ndarray]:
        """PBR maps (see :mod:`facegeo.asset`) from the homogenised texture; only ``maps``."""
        unknown = set(maps) - set(MAP_NAMES)
        if unknown:
            raise ValueError(f"maps: expected a subset of {MAP_NAMES}, got {sorted(unknown)}")
        cover = ctx.coverage
        out: dict[str, np.ndarray] = {}
        if "albedo" in maps:
            out["albedo"] = T_hom.astype(np.float32)
        needs_detail = bool({"normal", "displacement", "roughness", "specular"} & set(maps))
        if not needs_detail:
            return out
        log_l = np.log(np.maximum(luminance(srgb_to_linear(T_hom)), 1e-4))
        sigma = max(0.75, ctx.size * self.detail_sigma_fraction)
        detail = np.where(cover, log_l - masked_blur(log_l, cover, sigma), 0.0).astype(np.float32)
        if {"normal", "displacement"} & set(maps):
            displacement = self.displacement_gain_mm * np.clip(detail, -1.0, 1.0)  # dark detail = deeper
            if "displacement" in maps:
                out["displacement"] = pad_outside(displacement.astype(np.float32), cover)
            if "normal" in maps:
                out["normal"] = pad_outside(self._normal_from_height(displacement, ctx), cover)
        if {"roughness", "specular"} & set(maps):
            rough, spec = self._priors(ctx)
            strength = np.tanh(np.abs(masked_blur(np.abs(detail), cover, 2 * sigma)) * 10.0)
            if "roughness" in maps:  # fine relief scatters: more detail, rougher (up to +0.15)
                out["roughness"] = pad_outside(np.clip(rough + 0.15 * strength, 0.05, 1.0).astype(np.float32), cover)
            if "specular" in maps:  # pores and wrinkles hold less sebum film: up to −30 % specular
                out["specular"] = pad_outside(np.clip(spec * (1.0 - 0.3 * strength), 0.0, 1.0).astype(np.float32), cover)
        return out

    @staticmethod
    def _normal_from_height(height_mm: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """Tangent-space normals (S, S, 3) in [−1, 1] of a height field in mm: n ∝ (−∂h/∂u,
        −∂h/∂v, 1) with the derivatives per mm on the surface (+u = columns, +v = rows up)."""
        dh_dcol = np.gradient(height_mm, axis=1)
        dh_drow = np.gradient(height_mm, axis=0)
        du = np.maximum(ctx.texel_size_mm[..., 0], 1e-3)
        dv = np.maximum(ctx.texel_size_mm[..., 1], 1e-3)
        n = np.stack([-dh_dcol / du, dh_drow / dv, np.ones_like(height_mm)], axis=-1)
        return (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)

    @staticmethod
    def _priors(ctx: TextureContext) -> tuple[np.ndarray, np.ndarray]:
        """Region-weighted (roughness, specular) priors, (S, S) each."""
        shape = ctx.coverage.shape
        total = np.zeros(shape, np.float32)
        rough = np.zeros(shape, np.float32)
        spec = np.zeros(shape, np.float32)
        for name, (r, s) in REGION_PRIORS.items():
            if name in ctx.regions:
                w = ctx.regions[name].astype(np.float32)
                total += w
                rough += w * r
                spec += w * s
        rest = np.clip(1.0 - total, 0.0, 1.0)
        norm = np.maximum(total + rest, 1e-6)
        return (rough + rest * DEFAULT_PRIOR[0]) / norm, (spec + rest * DEFAULT_PRIOR[1]) / norm

    # ---------------------------------------------------------------------------------- upscale
    def upscale(self, map_: np.ndarray, factor: int) -> np.ndarray:
        """Lanczos upscaling by an integer ``factor`` (1 returns the map unchanged)."""
        if factor == 1:
            return map_
        if factor < 1:
            raise ValueError(f"upscale factor: expected an integer ≥ 1, got {factor}")
        h, w = map_.shape[:2]
        return cv2.resize(map_, (w * factor, h * factor), interpolation=cv2.INTER_LANCZOS4)
