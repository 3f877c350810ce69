"""The fill's fine detail by example: blocks of the seen skin's own finest detail quilted over the
texels to fill.

Where the photo does not show the skin, its fine detail (pores, stubble; finer than ~S/256
texels, ~1 mm at 1K) is this face's own texture at its own contrast: blocks of the reliably seen
skin's finest detail, each copied from the seen skin near the block's nearest seen place (a
stubbled jaw goes on under the chin, a smooth forehead onto the scalp), and none from a place
much busier than its neighbourhood (a mole, a lash, a wrinkle copied over the scalp shows as a
repeated mark). :func:`quilted_detail`; its knobs are ``settings.quilt_*``.
"""

from __future__ import annotations

import cv2
import numpy as np

from facegeo.texturing.default.settings import DEFAULT_SETTINGS, DefaultSettings

__all__ = ["quilted_detail"]


def quilted_detail(detail: np.ndarray, source: np.ndarray, need: np.ndarray, seed: int = 0, *,
                   settings: DefaultSettings = DEFAULT_SETTINGS) -> np.ndarray | None:
    """Detail (S, S, C) float32 over ``need`` (S, S) bool, made of blocks of ``detail`` (S, S, C)
    copied from places wholly inside ``source`` (S, S) bool and no busier than
    ``settings.quilt_energy_cap`` × the median place of their neighbourhood: blocks of
    ``settings.quilt_block`` × S texels on a half-overlapping grid, each from a place drawn uniformly
    within ``settings.quilt_neighbourhood`` × S / 2 texels of the place nearest to it (so the copy has
    the texture of the source next to it), made zero-mean under its separable Hann window and
    blended with variance-preserving weights Σ w·x / √(Σ w²), so the copy keeps the source's
    contrast at every scale finer than a block and no block edge shows.
    Deterministic for a given ``seed``. 0 outside ``need``; None where ``source`` holds no whole
    block. (By hand: OpenCV's and scikit-image's inpainting diffuse or copy whole regions; none
    synthesises a stationary detail layer by example.)"""
    size = detail.shape[0]
    half = max(4, round(settings.quilt_block * size / 2))
    block = 2 * half
    if size < block:
        return None
    inside = cv2.erode(source.astype(np.uint8), np.ones((block, block), np.uint8), anchor=(0, 0),
                       borderType=cv2.BORDER_CONSTANT, borderValue=0)[: size - block + 1, : size - block + 1]
    starts = np.argwhere(inside > 0)
    if len(starts) == 0:
        return None
    energy = cv2.boxFilter(np.einsum("...k,...k->...", detail, detail).astype(np.float32), -1, (block, block), anchor=(0, 0),
                           borderType=cv2.BORDER_CONSTANT)[starts[:, 0], starts[:, 1]]  # mean square over each block
    # too busy by the median of the square of side settings.quilt_neighbourhood × S that a place starts in
    side = max(block, round(settings.quilt_neighbourhood * size))
    square = (starts[:, 0] // side) * (size // side + 1) + starts[:, 1] // side
    order = np.argsort(square, kind="stable")
    _, first, counts = np.unique(square[order], return_index=True, return_counts=True)
    median = np.array([np.median(energy[order[a: a + n]]) if n >= block * block else np.nan for a, n in zip(first, counts)])
    limit = np.empty(len(starts))
    limit[order] = np.repeat(np.where(np.isnan(median), np.median(energy), median), counts)
    starts = starts[energy <= settings.quilt_energy_cap * limit]
    # each texel's nearest place (its block's centre), in the order of ``starts`` (row-major, as
    # OpenCV numbers the zero pixels)
    centres = np.ones((size, size), np.uint8)
    centres[starts[:, 0] + half, starts[:, 1] + half] = 0
    _, nearest = cv2.distanceTransformWithLabels(centres, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    nearest -= 1
    reach = settings.quilt_neighbourhood * size / 2
    ramp = np.sin(np.pi * (np.arange(block) + 0.5) / block) ** 2  # Hann: two at half overlap sum to 1
    window = (ramp[:, None] * ramp[None, :]).astype(np.float32)
    channels = detail.shape[2]
    # a canvas (channels first) padded by a block on each side; block (i, j) covers image rows (i − 1)·half … (i + 1)·half
    cells = size // half + 3
    canvas = np.zeros((channels, cells * half + block, cells * half + block), np.float32)
    weight = np.zeros(canvas.shape[1:], np.float32)
    # which half × half cells hold a texel to fill (cell k: image rows k·half …; −1 and past the end: none)
    padded = np.zeros(((cells + 1) * half, (cells + 1) * half), bool)
    padded[:size, :size] = need
    cell_need = padded.reshape(cells + 1, half, cells + 1, half).any(axis=(1, 3))
    cell_need[-1, :] = cell_need[:, -1] = False  # index −1 (the cell before row 0) is empty
    # every block of the detail (channels first, so that the gathered patches are contiguous), a view
    windows = np.lib.stride_tricks.sliding_window_view(np.ascontiguousarray(detail.transpose(2, 0, 1)), (block, block), axis=(1, 2))
    mean_weights = (window / window.sum()).reshape(-1)
    rng = np.random.default_rng(seed)
    offset = block - half  # image row 0 is canvas row `block`, so block i starts at canvas row offset + i·half
    for pr in (0, 1):  # four phases of the half-overlapping grid, each a tiling of disjoint blocks
        for pc in (0, 1):
            rows, cols = np.arange(pr, cells, 2), np.arange(pc, cells, 2)
            ii, jj = np.meshgrid(rows, cols, indexing="ij")
            touch = cell_need[ii - 1, jj - 1] | cell_need[ii - 1, jj] | cell_need[ii, jj - 1] | cell_need[ii, jj]
            if not touch.any():
                continue
            # a place at a random point within ``reach`` of the place nearest to the block's centre:
            # uniform over the places there, by rejection (snapping a point that misses to the
            # nearest place would copy the few places on the region's rim over and over: a brick
            # pattern); where settings.quilt_tries points miss, within twice and four times ``reach``,
            # then anywhere
            bi, bj = np.nonzero(touch)
            near = starts[nearest[np.clip(rows[bi] * half, 0, size - 1), np.clip(cols[bj] * half, 0, size - 1)]] + half
            scale = reach * np.repeat([1.0, 2.0, 4.0], settings.quilt_tries)[:, None]
            angle, radius = rng.uniform(0, 2 * np.pi, scale.shape[0:1] + bi.shape), scale * np.sqrt(rng.random(scale.shape[0:1] + bi.shape))
            point = np.rint(near + radius[..., None] * np.stack([np.sin(angle), np.cos(angle)], -1)).astype(int)
            on_map = np.all((point >= 0) & (point < size), axis=-1)
            point = np.clip(point, 0, size - 1)
            hit = on_map & (centres[point[..., 0], point[..., 1]] == 0)
            chosen = nearest[point[..., 0], point[..., 1]][hit.argmax(0), np.arange(len(bi))]
            pick = starts[np.where(hit.any(0), chosen, rng.integers(len(starts), size=len(bi)))]
            patches = windows[:, pick[:, 0], pick[:, 1]]  # (C, n, block, block), a copy
            patches -= (patches.reshape(channels, len(pick), -1) @ mean_weights)[:, :, None, None]  # zero mean under the window
            patches *= window
            r0, c0 = offset + pr * half, offset + pc * half
            h, w = len(rows) * block, len(cols) * block
            tiling = canvas[:, r0: r0 + h, c0: c0 + w].reshape(channels, len(rows), block, len(cols), block).transpose(0, 1, 3, 2, 4)
            tiling[:, touch] += patches  # (a view of the canvas: C, rows, cols, block, block)
            weight[r0: r0 + h, c0: c0 + w] += np.kron(touch.astype(np.float32), window * window)
    inner = (slice(block, block + size), slice(block, block + size))
    out = (canvas[:, inner[0], inner[1]] / np.sqrt(np.maximum(weight[inner], 1e-6))).transpose(1, 2, 0)
    return np.where(need[..., None], out, 0.0).astype(np.float32)
