"""The scan-conversion core shared by the UV rasteriser and the image renderer (NumPy, CPU).

Points are continuous pixel coordinates with the origin at the top-left corner of the grid, x to
the right and y downwards; pixel (column i, row j) has its centre at (i + 0.5, j + 0.5), the
convention of :mod:`facegeo.camera`. A pixel belongs to a triangle when its centre is inside; a
centre exactly on an edge belongs to exactly one of the two triangles sharing that edge (a
top-left-style tie rule made exact by evaluating every edge function from its endpoints in a
canonical order, so the two triangles compute bit-identical values of opposite sign). Triangles of
zero or non-finite area cover nothing. Both orientations are rasterised (mirrored UV islands and
back faces alike).

Each triangle contributes the pixel centres of its bounding box. Triangles are grouped by
bounding-box shape (rounded up to a few sizes) and each group is tested by broadcasting, with no
per-candidate gathers, in chunks of at most :data:`CHUNK` candidates, so memory stays bounded at
any resolution.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

#: Candidate pixels tested per vectorised chunk (about 100 bytes each while in flight).
CHUNK = 1 << 18


def triangle_fragments(
    points: np.ndarray, width: int, height: int, chunk: int = CHUNK
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """All (pixel, triangle) pairs whose pixel centre lies inside the triangle.

    Args:
        points: (F, 3, 2) float64 corner positions in pixels (x right, y down).
        width, height: the pixel grid.
        chunk: candidates per vectorised batch.
    Yields:
        Batches ``(pixel, triangle, barycentric)``: (K,) int64 flat pixel index ``row * width +
        col``, (K,) int64 triangle index, (K, 3) float64 screen-space barycentric coordinates of
        the pixel centre with respect to the triangle's corners in their given order (each in
        [0, 1], summing to 1). A pixel may appear once per overlapping triangle.
    """
    pts = np.asarray(points, dtype=np.float64)
    n = pts.shape[0]
    if n == 0 or width <= 0 or height <= 0:
        return
    xs, ys = pts[..., 0], pts[..., 1]
    with np.errstate(invalid="ignore", over="ignore"):
        area = (xs[:, 1] - xs[:, 0]) * (ys[:, 2] - ys[:, 0]) - (ys[:, 1] - ys[:, 0]) * (xs[:, 2] - xs[:, 0])
        finite = np.isfinite(pts).all(axis=(1, 2)) & np.isfinite(area)
        x0 = np.ceil(np.where(finite, xs.min(axis=1), 0.0) - 0.5)
        x1 = np.floor(np.where(finite, xs.max(axis=1), -1.0) - 0.5)
        y0 = np.ceil(np.where(finite, ys.min(axis=1), 0.0) - 0.5)
        y1 = np.floor(np.where(finite, ys.max(axis=1), -1.0) - 0.5)
    x0, y0 = np.clip(x0, 0, width), np.clip(y0, 0, height)
    x1, y1 = np.clip(x1, -1, width - 1), np.clip(y1, -1, height - 1)
    w = (x1 - x0 + 1).astype(np.int64)
    h = (y1 - y0 + 1).astype(np.int64)
    keep = finite & (area != 0) & (w > 0) & (h > 0)
    tri = np.flatnonzero(keep)
    if tri.size == 0:
        return
    w, h, x0, y0 = w[tri], h[tri], x0[tri].astype(np.int64), y0[tri].astype(np.int64)
    coef = _edge_coefficients(pts[tri], np.sign(area[tri]))  # (T, 3 edges, 4): A, B, C, owned
    # Triangles with equal bounding-box shapes are tested together by broadcasting (no
    # per-candidate gathers); shapes are bucketed so there are few batches.
    bw, bh = _bucket(w), _bucket(h)
    order = np.lexsort((bh, bw))
    key = bw[order] * (1 << 32) + bh[order]
    cuts = np.flatnonzero(np.diff(key)) + 1
    for group in np.split(order, cuts):
        gw, gh = int(bw[group[0]]), int(bh[group[0]])
        per = max(1, chunk // (gw * gh))
        for s in range(0, group.size, per):
            g = group[s : s + per]
            cols = x0[g][:, None, None] + np.arange(gw)[None, None, :]  # (G, 1, gw)
            rows = y0[g][:, None, None] + np.arange(gh)[None, :, None]  # (G, gh, 1)
            k = coef[g]
            px, py = cols + 0.5, rows + 0.5
            inside = (cols < width) & (rows < height)
            es = []
            for e_i in range(3):
                a, b, c, own = (k[:, e_i, j][:, None, None] for j in range(4))
                e = a * px + b * py + c
                inside = inside & ((e > 0) | ((e == 0) & (own > 0)))
                es.append(e)
            gi, ri, ci = np.nonzero(inside)
            if gi.size == 0:
                continue
            e = np.stack([es[j][gi, ri, ci] for j in range(3)], axis=1)
            bary = e / e.sum(axis=1, keepdims=True)
            row = y0[g][gi] + ri
            col = x0[g][gi] + ci
            yield row * width + col, tri[g[gi]], bary


def _bucket(n: np.ndarray) -> np.ndarray:
    """Round bounding-box sides up to a few sizes: exact up to 8, then steps of an eighth."""
    n = np.asarray(n, dtype=np.int64)
    step = np.maximum(1, 1 << np.maximum(0, np.ceil(np.log2(np.maximum(n, 1))).astype(np.int64) - 3))
    return np.where(n <= 8, n, -(-n // step) * step)


def _edge_coefficients(pts: np.ndarray, orientation: np.ndarray) -> np.ndarray:
    """(T, 3, 4) float64: for the edge opposite each corner, E(p) = A·x + B·y + C (positive
    inside) and whether a centre exactly on the edge is owned (1.0) or not (0.0).

    The endpoints are put in lexicographic order before A, B, C are computed, and the sign is
    applied afterwards, so the two triangles sharing an edge get exactly opposite coefficients
    and therefore exactly opposite values at every pixel centre.
    """
    p = pts[:, [1, 2, 0]]  # edge k runs from corner k+1 to corner k+2
    q = pts[:, [2, 0, 1]]
    swap = (p[..., 0] > q[..., 0]) | ((p[..., 0] == q[..., 0]) & (p[..., 1] > q[..., 1]))  # (T, 3)
    a = np.where(swap[..., None], q, p)
    b = np.where(swap[..., None], p, q)
    # E(x, y) = (b - a) × ((x, y) - a) for the edge a -> b, positive on its left
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    s = orientation[:, None] * np.where(swap, -1.0, 1.0)  # the sign that makes E positive inside
    out = np.empty((pts.shape[0], 3, 4), dtype=np.float64)
    out[..., 0] = s * -dy
    out[..., 1] = s * dx
    out[..., 2] = s * (dy * a[..., 0] - dx * a[..., 1])
    # inward normal (A, B): own the edge when it points down, or right if the edge is vertical
    nx, ny = out[..., 0], out[..., 1]
    out[..., 3] = (ny > 0) | ((ny == 0) & (nx > 0))
    return out
