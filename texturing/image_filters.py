"""Image filters on UV maps that every texture backend may use: Gaussian and masked blurs, area
averaging onto a coarser grid, a UV-space push-pull, the exact Euclidean distance transform and
the padding outside the UV islands.

Maps are image-style (S, S[, C]) arrays (:mod:`facegeo.texturing.backend`); blurs are float32
and their σ is in texels. Both backends pad every map with :func:`pad_outside` (the default
backend with :attr:`~facegeo.texturing.default.settings.DefaultSettings.pad_fraction`, whose
default is :data:`PAD_FRACTION`).
"""

from __future__ import annotations

import hashlib

import cv2
import numpy as np
from scipy import ndimage

__all__ = ["PAD_FRACTION", "area_mean", "euclidean_distance", "gaussian_blur", "masked_blur", "pad_outside", "pad_width",
           "push_pull"]

#: Padding outside the UV islands: the edge colour over this fraction of S texels (4 at 1K), then
#: the median of the map (flat).
PAD_FRACTION = 1.0 / 256.0


def gaussian_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur (reflected borders) of an (H, W[, C]) float32 image, σ in texels. Above σ =
    8 texels it runs on a copy downsampled by a power of two (area averaging) and is upsampled
    bilinearly: the result is smooth at that scale anyway, and a direct 6σ kernel at σ = S/5 costs
    seconds. Returns float32 of the image's shape."""
    image = np.asarray(image, np.float32)
    factor = 1
    while sigma / (factor * 2) >= 4.0 and min(image.shape[:2]) // (factor * 2) >= 8:
        factor *= 2
    if factor == 1:  # (OpenCV drops a single channel's axis: the shape is restored)
        return cv2.GaussianBlur(image, (0, 0), sigma, borderType=cv2.BORDER_REFLECT).reshape(image.shape)
    h, w = image.shape[:2]
    small = cv2.resize(image, (max(1, w // factor), max(1, h // factor)), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), sigma / factor, borderType=cv2.BORDER_REFLECT)
    out = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    return out.reshape(image.shape)


def masked_blur(image: np.ndarray, weight: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur (σ texels) of ``image`` (S, S[, C]) that only averages texels with ``weight``
    (S, S) > 0: blur(w·x) / blur(w), float32. Texels with no weighted neighbour within ~3σ get 0."""
    w = weight.astype(np.float32)
    return _blurred_over(image * (w[..., None] if image.ndim == 3 else w), w, sigma)[0]


def _blurred_over(weighted: np.ndarray, w: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`masked_blur` of the image whose product with its float32 weight ``w`` is
    ``weighted``, and blur(w) (S, S), the weight's own blur (what :func:`push_pull` calls support)."""
    coverage = gaussian_blur(w, sigma)
    den = np.maximum(coverage, 1e-6)
    return gaussian_blur(weighted, sigma) / (den[..., None] if weighted.ndim == 3 else den), coverage


def area_mean(image: np.ndarray, weight: np.ndarray, grid: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``image`` (H, W, C) float32 averaged over ``weight`` (H, W) onto ``grid`` (width, height;
    OpenCV's area resampling), and the weight's own average (grid), both float32."""
    w = cv2.resize(weight.astype(np.float32), grid, interpolation=cv2.INTER_AREA)
    x = cv2.resize(image * weight[..., None], grid, interpolation=cv2.INTER_AREA) / np.maximum(w, 1e-6)[..., None]
    return x, w


def push_pull(values: np.ndarray, weight: np.ndarray, size: int, finest: float, mean: np.ndarray) -> np.ndarray:
    """UV-space extrapolation of (S, S, C) ``values`` known with ``weight`` (S, S): ``mean`` (C,),
    then masked blurs from S/2 texels down to ``finest`` texels by factors of 4, each finer level
    kept where it has support. Returns (S, S, C) float32."""
    out = np.broadcast_to(np.asarray(mean, np.float32), values.shape)
    sigmas = [size / 2.0]
    while sigmas[-1] / 4 >= max(finest, 0.5):
        sigmas.append(sigmas[-1] / 4)
    w = weight.astype(np.float32)
    weighted = values * w[..., None]  # the same at every level, as the weight's blur is for the blend and the support
    for sigma in sigmas:
        blurred, coverage = _blurred_over(weighted, w, sigma)
        support = np.clip(coverage * 4.0, 0.0, 1.0)[..., None]
        out = support * blurred + (1 - support) * out
    return out


#: OpenCV's exact distance transform returns float32 distances; the integer squared distance is
#: recovered from them exactly while it stays below 2^22 (float32 sqrt keeps d² within ±0.5).
_EXACT_SQUARED = float(1 << 22)


def euclidean_distance(mask: np.ndarray) -> np.ndarray:
    """(H, W) float64 Euclidean distance in texels from each True texel of the (H, W) bool
    ``mask`` to the nearest False one (0 on False texels), bit-identical to
    ``scipy.ndimage.distance_transform_edt``: OpenCV's exact transform (Felzenszwalb's algorithm,
    ``DIST_MASK_PRECISE``, several times faster) gives d in float32, d² is rounded back to its
    integer and its float64 root taken, as SciPy does. SciPy itself where d² could lose that
    integer or no texel is False."""
    if mask.all():
        return ndimage.distance_transform_edt(mask)
    distance = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    squared = np.rint(np.square(distance, dtype=np.float64))
    if squared.max() >= _EXACT_SQUARED:
        return ndimage.distance_transform_edt(mask)
    return np.sqrt(squared)


#: pad_outside's nearest-texel tables per (mask, width) digest, at most 4.
_NEAREST_CACHE: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}


def pad_width(size: int, fraction: float = PAD_FRACTION) -> int:
    """The padding's edge band in texels for an S = ``size`` map: ``fraction`` × S, at least 2."""
    return max(2, int(round(size * fraction)))


def pad_outside(image: np.ndarray, inside: np.ndarray, width: int | None = None) -> np.ndarray:
    """Pad an (S, S[, C]) map outside ``inside`` (S, S) bool: texels within ``width`` texels of
    the layout (default :func:`pad_width` of S) take the value of the nearest inside texel
    (bilinear sampling and the first mip levels never see the background), those further out one
    value, flat (no streaks: a neutral padding): the inside texel nearest the per-channel median (a
    real texel value, so a normal map's padding is a unit normal). Returns the map's dtype and
    shape (``image`` itself where ``inside`` is all or nothing). The nearest-texel table is cached
    per mask (a layout pads all its maps with the same one)."""
    if inside.all() or not inside.any():
        return image
    width = pad_width(inside.shape[0]) if width is None else int(width)
    key = hashlib.blake2b(np.packbits(inside).tobytes() + str(inside.shape).encode() + str(width).encode(),
                          digest_size=16).digest()
    if key not in _NEAREST_CACHE:
        if len(_NEAREST_CACHE) >= 4:
            _NEAREST_CACHE.clear()
        distance, (rows, cols) = ndimage.distance_transform_edt(~inside, return_indices=True)
        near = np.flatnonzero(~inside.ravel() & (distance.ravel() <= width))
        source = (rows.ravel()[near] * inside.shape[1] + cols.ravel()[near]).astype(np.int64)
        far = np.flatnonzero(distance.ravel() > width)
        _NEAREST_CACHE[key] = (near, source, far, np.flatnonzero(inside.ravel())[::7])
    near, source, far, sample = _NEAREST_CACHE[key]
    flat_view = image.reshape(inside.size, -1)
    out = flat_view.copy()
    out[near] = flat_view[source]
    values = flat_view[sample]  # a seventh of the inside texels: the median within rounding
    middle = values[np.argmin(np.abs(values - np.median(values, axis=0)).sum(axis=1))]
    out[far] = middle  # the texel nearest the median: a real value (a unit normal stays unit)
    return out.reshape(image.shape)
