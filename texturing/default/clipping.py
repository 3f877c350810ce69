"""Clipped texels: a channel at ``settings.clipped_level`` (over-exposed skin) is a lower bound, not a
measurement. Where only some channels are clipped, those are raised to what the others and the
surrounding skin's colour ratios imply (:func:`restore_clipped`), before the analysis, and the
texel is then used as any other; a texel with every channel clipped stays a lower bound and is
left out of every fit.
"""

from __future__ import annotations

import cv2
import numpy as np

from facegeo.colour import channel_sum, srgb_to_linear
from facegeo.texturing.default.settings import DEFAULT_SETTINGS, DefaultSettings
from facegeo.texturing.image_filters import area_mean, push_pull

__all__ = ["clipped_ceiling", "restore_clipped"]


def clipped_ceiling(settings: DefaultSettings) -> np.float32:
    """The linear value of ``settings.clipped_level``: a channel at or above it is clipped."""
    return srgb_to_linear(np.float32(settings.clipped_level))


def restore_clipped(lin: np.ndarray, valid: np.ndarray, size: int, *,
                    settings: DefaultSettings = DEFAULT_SETTINGS) -> np.ndarray:
    """(S, S, 3) linear RGB ``lin`` with each clipped channel (at or above ``settings.clipped_level``)
    raised to what the texel's unclipped channels imply under the local colour ratios of the
    unclipped ``valid`` (S, S) bool texels (their mean colour on a grid 4× coarser, in log RGB
    extended by :func:`~facegeo.texturing.image_filters.push_pull` down to S/128 texels: a
    clipped cheek takes the chroma of the skin around it), never lowered; texels with every
    channel clipped, and a map without unclipped valid texels, are left as they are. (As a raw converter's highlight reconstruction
    by colour propagation; no library here does it.)"""
    clipped = lin >= clipped_ceiling(settings)
    count = channel_sum(clipped.view(np.uint8))
    rows, cols = np.nonzero((count > 0) & (count < 3))
    free = valid & (count == 0)
    if len(rows) == 0 or free.sum() < 10:
        return lin
    grid = (max(1, size // 4), max(1, size // 4))
    local, weight = area_mean(lin, free, grid)
    log_local = np.log(np.maximum(local, 1e-4))
    mean = np.log(np.maximum(lin[free].mean(axis=0), 1e-4))
    ref = cv2.resize(push_pull(log_local, weight, grid[0], grid[0] / 128.0, mean), (lin.shape[1], lin.shape[0]),
                     interpolation=cv2.INTER_LINEAR)[rows, cols]
    # the reference's level moved onto the texel's unclipped channels (the mean log offset over them)
    value, cut = lin[rows, cols], clipped[rows, cols]
    offset = np.where(cut, 0.0, np.log(np.maximum(value, 1e-4)) - ref).sum(axis=-1, keepdims=True) / (~cut).sum(axis=-1, keepdims=True)
    out = lin.copy()
    out[rows, cols] = np.where(cut, np.maximum(value, np.exp(ref + offset)), value)
    return out
