"""One albedo from several photos of one person: each texel from the photos that see it best.

Each photo gives a de-lit albedo in UV space (its own light and camera taken out by the texture
backend: complete for the reference photo, the others' where they saw the skin) and a weight per
texel, how well it saw the surface there (:func:`view_weight`: the backend's reliability of the
seen texel × the photo's pixels per mm² of surface, (f / d)² · cos θ). :func:`fuse_albedos` then

1. matches exposure and white balance: each photo's albedo is scaled per channel so that, on the
   skin both it and the reference photo see well, its median log ratio to the reference is 0
   (:data:`MIN_COMMON_TEXELS` such texels at least; otherwise it is scaled by the median gain of
   the photos that could be matched, and a note says so);
2. continues each photo's albedo beyond what it saw (``image_filters.push_pull``), so that no band of the blend
   mixes in the values of texels it did not see;
3. blends the photos with multi-band blending (Burt & Adelson 1983): the weights, sharpened
   (``weight ** SHARPNESS``, so the best view dominates), are smoothed more at each coarser level
   of a Gaussian pyramid and each level of the albedos' Laplacian pyramids (in log space, so the
   blend of two exposures is their geometric mean) is averaged with them: fine detail comes from
   the photo that sees a texel best, the tone varies smoothly between photos, and no seam
   follows a weight's edge. Texels no photo saw take the reference's albedo (its backend's fill).

By hand: OpenCV's ``detail.MultiBandBlender`` blends images in one plane with hard masks and
8/16-bit data; here the weights are soft, the data float and the result must stay a per-texel
weighted mean where one photo alone saw the texel.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from facegeo.concurrency import run_concurrently, usable_threads
from facegeo.texturing.image_filters import push_pull

__all__ = ["fuse_albedos", "view_weight", "MIN_COMMON_TEXELS", "MAX_EXPOSURE", "MAX_WHITE_BALANCE", "SHARPNESS", "LEVELS"]

#: Skin texels seen well (weight ≥ half its photo's 90th percentile) by both a photo and the
#: reference that its exposure and white balance are matched on.
MIN_COMMON_TEXELS = 200
#: A photo whose matched gains differ from the reference's by more than this factor in exposure
#: (any channel), or by more than :data:`MAX_WHITE_BALANCE` between its channels, is left out:
#: after each photo's own light and its colour are taken out, so large a difference is another
#: face or a failed fit, not another exposure (±2 EV) or a white balance left in.
MAX_EXPOSURE = 4.0
MAX_WHITE_BALANCE = 1.5
#: Exponent of the weights before blending (the best-seeing photo dominates each texel).
SHARPNESS = 4.0
#: Pyramid levels of the blend: its coarsest band is 2^LEVELS texels (16), the scale over which
#: the tone passes from one photo to another (at S = 1024, ~3 mm on the cheek).
LEVELS = 4


def view_weight(visibility: np.ndarray, cos_view: np.ndarray, distance_mm: np.ndarray, focal_px: float) -> np.ndarray:
    """How well one photo saw each texel: (S, S) float32 ``visibility`` (in [0, 1]: ``M_vis``, or
    the texture backend's reliability of the seen texel) × the photo's pixels per mm² of surface there, (f / d)² · cos θ, with ``cos_view`` (S, S) cos θ,
    ``distance_mm`` (S, S) the texel's distance from the camera (mm) and ``focal_px`` the focal
    length in pixels. 0 where the photo did not see the texel."""
    d = np.maximum(np.asarray(distance_mm, np.float64), 1.0)
    density = (float(focal_px) / d) ** 2 * np.clip(np.asarray(cos_view, np.float64), 0.0, 1.0)
    return (np.clip(visibility, 0.0, 1.0) * density).astype(np.float32)


def fuse_albedos(albedos: Sequence[np.ndarray], weights: Sequence[np.ndarray], skin: np.ndarray, coverage: np.ndarray,
                 reference: int = 0, names: Sequence[str] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Blend K photos' albedos into one (module docstring).

    Args:
        albedos: K (S, S, 3) float32 linear-RGB albedos in [0, 1]: the reference's complete over
            ``coverage``, the others' valid where their weight is > 0.
        weights: K (S, S) float32 ≥ 0, how well each photo saw each texel (:func:`view_weight`).
        skin: (S, S) bool, the skin texels exposure and white balance are matched on.
        coverage: (S, S) bool, the texels of the layout.
        reference: the photo whose exposure and white balance the others are matched to, and
            whose albedo fills the texels no photo saw.
        names: the photos' names for the notes (default: "photo <index>").
    Returns:
        ``(albedo (S, S, 3) float32 linear RGB in [0, 1], 0 outside coverage; report)``: the
        report holds per photo its ``gains`` (3,), the ``common_texels`` it was matched on, the
        ``share`` of the covered texels it contributes most to, and ``notes``.
    Raises:
        ValueError: no photos, or arrays of different shapes.
    """
    if not albedos or len(albedos) != len(weights):
        raise ValueError(f"fuse_albedos: {len(albedos)} albedos and {len(weights)} weights")
    size = albedos[0].shape[:2]
    if any(a.shape != (*size, 3) for a in albedos) or any(w.shape != size for w in weights):
        raise ValueError("fuse_albedos: every albedo must be (S, S, 3) and every weight (S, S) of the same S")
    K = len(albedos)
    names = [f"photo {k}" for k in range(K)] if names is None else list(names)
    logs = [np.log(np.clip(a, 1e-4, 1.0)).astype(np.float32) for a in albedos]
    strong = [w >= 0.5 * max(float(np.percentile(w[w > 0], 90)) if (w > 0).any() else 0.0, 1e-12) for w in weights]
    notes: list[str] = []
    gains = np.zeros((K, 3), np.float64)
    common = [0] * K
    matched = [reference]
    for k in range(K):
        if k == reference:
            continue
        both = strong[k] & strong[reference] & skin & coverage
        common[k] = int(both.sum())
        if common[k] >= MIN_COMMON_TEXELS:
            gains[k] = np.median(logs[reference][both] - logs[k][both], axis=0)
            matched.append(k)
    implausible = [k for k in matched[1:] if np.abs(gains[k]).max() > np.log(MAX_EXPOSURE)
                   or gains[k].max() - gains[k].min() > np.log(MAX_WHITE_BALANCE)]
    for k in implausible:
        matched.remove(k)
        notes.append(f"{names[k]}: left out of the texture: its albedo differs from the reference's by gains "
                     f"{', '.join(f'{g:.2f}' for g in np.exp(gains[k]))} (another face, a failed fit or a photo without colour)")
    unmatched = [k for k in range(K) if k not in matched and k not in implausible]
    if unmatched:
        fallback = np.median(gains[matched], axis=0) if len(matched) > 1 else np.zeros(3)
        gains[unmatched] = fallback
        notes.append(f"{', '.join(names[k] for k in unmatched)}: fewer than {MIN_COMMON_TEXELS} well-seen skin texels shared "
                     "with the reference: exposure and white balance not matched (the others' median gain used)")
    logs = [lg + gains[k].astype(np.float32) for k, lg in enumerate(logs)]
    # each photo's albedo continued smoothly beyond what it saw, so that the blend's coarse bands,
    # which reach past a weight's edge, average colours it saw, not the zeros of what it did not
    # (the reference's own fill stays where no photo saw the skin)
    weights = [np.zeros_like(w) if k in implausible else w for k, w in enumerate(weights)]
    nobody = ~np.any([w > 0 for w in weights], axis=0)
    logs = run_concurrently([functools.partial(_continued, lg, ((weights[k] > 0) | (nobody if k == reference else False)) & coverage)
                             for k, lg in enumerate(logs)], usable_threads())

    sharp = [np.where(coverage, w.astype(np.float64), 0.0) ** SHARPNESS for w in weights]
    scale = max(float(max(s.max() for s in sharp)), 1e-30)
    sharp = [(s / scale).astype(np.float32) for s in sharp]
    seen = ~nobody
    # texels no photo saw: the reference's albedo (a weight far below any seen texel's)
    floor = np.float32(1e-6) * np.where(coverage & nobody, 1.0, 1e-6).astype(np.float32)
    sharp[reference] = sharp[reference] + floor
    blended = _multiband(logs, sharp, max(1, min(LEVELS, int(np.log2(min(size))) - 3)))
    fused = np.where(coverage[..., None], np.exp(blended), 0.0)
    best = np.argmax(np.stack(sharp), axis=0)
    share = [float((best[coverage & seen] == k).mean()) if (coverage & seen).any() else 0.0 for k in range(K)]
    report = {"reference": int(reference), "gains": np.exp(gains).round(4).tolist(), "common_texels": common, "share": share,
              "notes": notes}
    return np.clip(fused, 0.0, 1.0).astype(np.float32), report


def _continued(image: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``image`` (S, S, C) float32 where ``valid`` (S, S) bool, continued into the other texels
    by :func:`~facegeo.texturing.image_filters.push_pull` (down to one texel)."""
    if valid.all() or not valid.any():
        return image
    extended = push_pull(image, valid.astype(np.float32), image.shape[0], 1.0, image[valid].mean(axis=0))
    return np.where(valid[..., None], image, extended).astype(np.float32)


def _multiband(images: Sequence[np.ndarray], weights: Sequence[np.ndarray], levels: int) -> np.ndarray:
    """Σ_k w_k x_k / Σ_k w_k band by band: each image's Laplacian pyramid level averaged with its
    weight's Gaussian pyramid level at that scale, then collapsed. (S, S, C) float32 images and
    (S, S) float32 weights (not all zero anywhere after the reference's floor)."""
    shape = images[0].shape
    num = [np.zeros(_level_shape(shape, i), np.float64) for i in range(levels + 1)]
    den = [np.zeros(_level_shape(shape, i)[:2], np.float64) for i in range(levels + 1)]
    for image, weight in zip(images, weights):
        gauss_w = [weight]
        gauss_x = [image]
        for _ in range(levels):
            gauss_w.append(cv2.pyrDown(gauss_w[-1]))
            gauss_x.append(cv2.pyrDown(gauss_x[-1]))
        for i in range(levels + 1):
            band = gauss_x[i] if i == levels else gauss_x[i] - cv2.pyrUp(gauss_x[i + 1], dstsize=(gauss_x[i].shape[1], gauss_x[i].shape[0]))
            num[i] += band * gauss_w[i][..., None]
            den[i] += gauss_w[i]
    out = num[levels] / np.maximum(den[levels], 1e-30)[..., None]
    for i in range(levels - 1, -1, -1):
        out = cv2.pyrUp(out.astype(np.float32), dstsize=(num[i].shape[1], num[i].shape[0])) + num[i] / np.maximum(den[i], 1e-30)[..., None]
    return out.astype(np.float32)


def _level_shape(shape: tuple[int, ...], level: int) -> tuple[int, ...]:
    """The shape of pyramid level ``level`` of an (H, W, C) image (cv2.pyrDown rounds up)."""
    h, w = shape[:2]
    for _ in range(level):
        h, w = (h + 1) // 2, (w + 1) // 2
    return (h, w, *shape[2:])
