"""The UV and pixel conventions in code: uv ↔ texel coordinates and bilinear lookups.

UV (DESIGN.md): [0, 1]², origin bottom-left (USD's ``st``). Maps are stored image-style, row 0 =
top, so texel (row i, column j) of an H × W map has its centre at

    u = (j + 0.5) / W,    v = 1 − (i + 0.5) / H.

As continuous texel coordinates this is the photo's pixel convention (:mod:`facegeo.camera`:
origin at the top-left corner, pixel centres at +0.5): ``x = u·W``, ``y = (1 − v)·H``. Every
conversion between the two goes through :func:`uv_to_texel`, :func:`nearest_texel` and
:func:`texel_centres_uv`; every bilinear lookup of a photo or a map through
:func:`sample_bilinear` (pixel coordinates) or :func:`sample_uv` (UVs).

The lookups are OpenCV's ``remap`` (bilinear, edge pixels repeated beyond the border; its weights
are quantised to 1/32 pixel), in float32. The differentiable lookup of the regressor's photometric
term stays ``torch.nn.functional.grid_sample``.
"""

from __future__ import annotations

import cv2
import numpy as np

from facegeo.errors import InputError

__all__ = ["uv_to_texel", "nearest_texel", "texel_centres_uv", "sample_bilinear", "sample_uv"]

#: Points per row of the coordinate maps handed to ``cv2.remap`` (its maps must be < 32767 a side).
_ROW = 4096


def uv_to_texel(uv: np.ndarray, height: int, width: int) -> np.ndarray:
    """(..., 2) UVs -> (..., 2) continuous texel coordinates (x = column, y = row; corner origin,
    centres at +0.5) of an ``height`` × ``width`` map, in ``uv``'s float dtype: x = u·W, y = (1 − v)·H."""
    uv = np.asarray(uv)
    if not np.issubdtype(uv.dtype, np.floating):
        uv = uv.astype(np.float64)
    out = np.empty_like(uv)
    out[..., 0] = uv[..., 0] * width
    out[..., 1] = (1.0 - uv[..., 1]) * height
    return out


def nearest_texel(uv: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(row, column) int64 arrays of the texel whose square holds each (..., 2) UV, clamped to the
    map (a UV on a texel border goes to the texel below/right of it)."""
    xy = uv_to_texel(uv, height, width)
    rows = np.clip(np.floor(xy[..., 1]), 0, height - 1).astype(np.int64)
    cols = np.clip(np.floor(xy[..., 0]), 0, width - 1).astype(np.int64)
    return rows, cols


def texel_centres_uv(size: int) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) of the texel centres of an S × S map, each (S, S) float64 (row 0 = top)."""
    c = (np.arange(size) + 0.5) / size
    return np.broadcast_to(c[None, :], (size, size)), np.broadcast_to(1.0 - c[:, None], (size, size))


def sample_bilinear(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear values of an image at continuous pixel coordinates (corner origin, the camera's).

    Args:
        image: (H, W) or (H, W, C) array (any number of channels), read as float32.
        xy: (..., 2) pixel coordinates (x right, y down); beyond the outer pixel centres the edge
            pixels repeat.
    Returns:
        (...) or (..., C) float32.
    """
    img = np.asarray(image, dtype=np.float32)
    if img.ndim not in (2, 3) or min(img.shape[:2]) < 1:
        raise InputError("<array>", "image", "an (H, W) or (H, W, C) array", f"shape {img.shape}")
    xy = np.asarray(xy)
    lead = xy.shape[:-1]
    flat = xy.reshape(-1, 2).astype(np.float32) - np.float32(0.5)  # remap's centres are integers
    n = len(flat)
    rows = max(1, -(-n // _ROW))
    maps = np.full((2, rows * _ROW), -1.0, np.float32)
    maps[:, :n] = flat.T
    map_x, map_y = maps[0].reshape(rows, _ROW), maps[1].reshape(rows, _ROW)
    channels = img[..., None] if img.ndim == 2 else img
    parts = [cv2.remap(np.ascontiguousarray(channels[..., c:c + 4]), map_x, map_y, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE).reshape(rows * _ROW, -1)
             for c in range(0, channels.shape[2], 4)]  # OpenCV remaps up to 4 channels at a time
    out = np.concatenate(parts, axis=1)[:n]
    return out.reshape(lead) if img.ndim == 2 else out.reshape(*lead, channels.shape[2])


def sample_uv(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear values of an (H, W) or (H, W, C) map at (..., 2) UVs: (...) or (..., C) float32
    (:func:`sample_bilinear` at :func:`uv_to_texel`)."""
    img = np.asarray(image)
    if img.ndim not in (2, 3):
        raise InputError("<array>", "map", "an (H, W) or (H, W, C) array", f"shape {img.shape}")
    return sample_bilinear(img, uv_to_texel(uv, img.shape[0], img.shape[1]))
