"""sRGB transfer functions (IEC 61966-2-1), luminance, the per-channel reductions of colours and
the test for a greyscale photo: the one home of the sRGB curves.

NumPy (float32, any shape) for I/O and the texture stage; :func:`srgb_to_linear_slope` (float64,
with the derivative) for linearising model files; the ``*_torch`` twins (differentiable, any
shape; torch is not imported here: they use tensor methods only) for losses.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch

__all__ = ["is_greyscale", "srgb_to_linear", "srgb8_to_linear", "linear_to_srgb", "srgb_to_linear_slope", "srgb_to_linear_torch", "linear_to_srgb_torch",
           "luminance", "channel_max", "channel_min", "channel_sum"]


def srgb_to_linear(srgb: np.ndarray) -> np.ndarray:
    """Decode sRGB values in [0, 1] to linear RGB (float32, same shape)."""
    s = np.asarray(srgb, dtype=np.float32)
    return np.where(s <= 0.04045, s / 12.92, ((np.maximum(s, 0.0) + 0.055) / 1.055) ** 2.4).astype(np.float32)


def srgb8_to_linear(codes: np.ndarray) -> np.ndarray:
    """Decode 8-bit sRGB codes (uint8, any shape) to linear RGB (float32, same shape) through a
    256-entry table: the numbers of ``srgb_to_linear(codes.astype(np.float32) / 255)``, without a
    power per pixel (a 512² photo: about a tenth of the time)."""
    if codes.dtype != np.uint8:
        raise TypeError(f"srgb8_to_linear: expected uint8 codes, got {codes.dtype}")
    return np.take(_SRGB8_TABLE, codes)


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """Encode linear RGB (values ≥ 0; clipped to [0, 1]) to sRGB in [0, 1] (float32)."""
    x = np.clip(np.asarray(linear, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055).astype(np.float32)


#: The linear value of each 8-bit sRGB code (:func:`srgb8_to_linear`).
_SRGB8_TABLE = srgb_to_linear(np.arange(256, dtype=np.float32) / 255.0)
_SRGB8_TABLE.setflags(write=False)


def srgb_to_linear_slope(srgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear values and the derivative d(linear)/d(sRGB), both float64, for sRGB clipped to [0, 1]."""
    s = np.clip(np.asarray(srgb, dtype=np.float64), 0.0, 1.0)
    low = s <= 0.04045
    lin = np.where(low, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)
    slope = np.where(low, 1.0 / 12.92, 2.4 / 1.055 * ((s + 0.055) / 1.055) ** 1.4)
    return lin, slope


def srgb_to_linear_torch(s: "torch.Tensor") -> "torch.Tensor":
    """The torch twin of :func:`srgb_to_linear` (not clamped at 1), differentiable, the tensor's dtype."""
    return (s / 12.92).where(s <= 0.04045, ((s.clamp_min(0.0) + 0.055) / 1.055) ** 2.4)


def linear_to_srgb_torch(x: "torch.Tensor", clip: bool = True) -> "torch.Tensor":
    """The torch twin of :func:`linear_to_srgb`, differentiable. ``clip=False`` skips the clip to
    [0, 1] (values above 1 follow the curve, negative ones its linear toe), so gradients pass for
    overshoot too."""
    if clip:
        x = x.clamp(0.0, 1.0)
    return (12.92 * x).where(x <= 0.0031308, 1.055 * x.clamp_min(0.0031308) ** (1 / 2.4) - 0.055)


def luminance(linear: np.ndarray, dtype: type = np.float32) -> np.ndarray:
    """Rec. 709 relative luminance of linear RGB (..., 3) -> (...), computed in ``dtype``."""
    rgb = np.asarray(linear, dtype=dtype)
    return (0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2]).astype(dtype)


def channel_max(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 1): the largest channel (``rgb.max(axis=-1, keepdims=True)``, without
    NumPy's slow reduction over a length-3 axis, ~10× slower)."""
    return np.maximum(np.maximum(rgb[..., 0], rgb[..., 1]), rgb[..., 2])[..., None]


def channel_min(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) -> (...): the smallest channel (``rgb.min(axis=-1)``, as :func:`channel_max`)."""
    return np.minimum(np.minimum(rgb[..., 0], rgb[..., 1]), rgb[..., 2])


def channel_sum(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) -> (...): the channels' sum (``rgb.sum(axis=-1)``, as :func:`channel_max`; a
    bool array's as 0/1 needs ``rgb.view(np.uint8)``)."""
    return rgb[..., 0] + rgb[..., 1] + rgb[..., 2]


def is_greyscale(srgb: np.ndarray, tolerance: float = 2.5 / 255.0) -> bool:
    """True when at least 99 % of the (N, 3) sRGB colours have R, G and B within ``tolerance``
    of each other (a greyscale photo stored as RGB, JPEG noise allowed)."""
    srgb = np.asarray(srgb, np.float32).reshape(-1, 3)
    if len(srgb) == 0:
        return False
    spread = channel_max(srgb)[:, 0] - channel_min(srgb)
    return float(np.mean(spread <= tolerance)) >= 0.99
