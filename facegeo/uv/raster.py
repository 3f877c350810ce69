"""The UV rasteriser: per texel, the triangle that covers it and its barycentric coordinates.

Texel convention (DESIGN.md, "Conventions"): the UV square [0, 1]² has its origin bottom-left; a map of size S is
stored row 0 = top, so texel (row i, column j) has its centre at u = (j + 0.5)/S,
v = 1 − (i + 0.5)/S. A texel is *inside* when its centre lies in a UV triangle (the exact tie rule
of :mod:`facegeo.uv._triangles` gives a centre on a shared edge to one triangle only); zero-area UV
triangles cover nothing.

Seam padding: every texel within ``padding`` texels (chessboard distance, i.e. dilation by a
(2n+1)² square) of an inside texel is *padded*: it takes the triangle of the nearest inside texel
and the barycentric coordinates of the point of that triangle closest to its centre, so maps made
from the raster continue the surface across island borders without overshoot. With padding n, a
bilinear lookup anywhere inside the layout at mip level k (box-filtered 2^k × 2^k) touches only
inside or padded texels while 2^(k+1) ≤ n (k ≤ 2 for the default 8 at S = 1024); ``padding >= size``
fills the whole square.

:func:`rasterize_uv` caches its result per layout (a digest of the UV coordinates and UV
triangles), size and padding: in the process, and on disk (:mod:`facegeo.layout_cache`, with the
dense views :data:`DISK_VIEWS`), so the cost is paid once per layout and code version.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Mapping
from functools import cached_property

import cv2
import numpy as np

from facegeo.errors import InputError
from facegeo.layout_cache import entry_folder, load_or_make
from facegeo.uv._triangles import triangle_fragments
from facegeo.uv.texels import uv_to_texel

__all__ = ["UVRaster", "rasterize_uv", "default_padding", "clear_raster_cache"]

#: Largest supported map side (flat texel indices are int32).
MAX_SIZE = 16384
#: Rasters kept in the cache (least recently used dropped first), and the byte budget.
CACHE_ENTRIES = 6
CACHE_BYTES = 2 << 30
#: The dense views kept in the disk cache with the per-texel arrays: those the pipeline reads
#: (``triangle`` and ``barycentric``, 16 MB more at S = 1024, are built on first access).
DISK_VIEWS = ("inside", "mask")

#: The per-texel arrays of a :class:`UVRaster`, in its constructor's order.
_COMPACT = ("texels", "texel_triangle", "texel_barycentric", "texel_inside")

_CACHE: OrderedDict[tuple[str, int, int], "UVRaster"] = OrderedDict()
_CACHE_LOCK = threading.Lock()


def default_padding(size: int) -> int:
    """The default seam padding in texels: S/128, at least 2 (8 at S = 1024, 32 at 4096)."""
    return max(2, int(size) // 128)


class UVRaster:
    """Which triangle covers each texel of an S × S UV map, with barycentric coordinates.

    The data are stored compactly for the N texels that have a triangle (inside or padded); the
    dense (S, S) views are built on first access (or come with the raster: ``views``). All arrays
    are read-only (rasters are shared through the cache).

    Attributes:
        size: S.
        padding: the seam padding in texels.
        n_triangles: F, the number of triangles of the layout.
        texels: (N,) int64 flat texel indices ``row * S + col``, ascending.
        texel_triangle: (N,) int64 triangle index of each texel.
        texel_barycentric: (N, 3) float32 barycentric coordinates with respect to the triangle's
            corners in ``uv_triangles`` order (each ≥ 0, summing to 1; for padded texels the
            closest point of the triangle).
        texel_inside: (N,) bool, True where the texel centre is inside the triangle.
        key: the cache key (layout digest).

    ``views``: dense views already made (name of the property -> its array, e.g. ``inside``
    loaded from the disk cache), used instead of building them.
    """

    def __init__(self, size: int, padding: int, n_triangles: int, texels: np.ndarray, texel_triangle: np.ndarray,
                 texel_barycentric: np.ndarray, texel_inside: np.ndarray, key: str = "",
                 views: Mapping[str, np.ndarray] | None = None):
        self.size = int(size)
        self.padding = int(padding)
        self.n_triangles = int(n_triangles)
        self.texels = _frozen(texels.astype(np.int64, copy=False))
        self.texel_triangle = _frozen(texel_triangle.astype(np.int64, copy=False))
        self.texel_barycentric = _frozen(texel_barycentric.astype(np.float32, copy=False))
        self.texel_inside = _frozen(texel_inside.astype(bool, copy=False))
        self.key = key
        for name, view in (views or {}).items():
            if not isinstance(getattr(type(self), name, None), cached_property):
                raise ValueError(f"{name!r} is not a dense view of a UVRaster")
            self.__dict__[name] = _frozen(view)  # where cached_property keeps the value it built

    def __repr__(self) -> str:
        n_in = int(self.texel_inside.sum())
        return (f"UVRaster(size={self.size}, padding={self.padding}, inside={n_in}, "
                f"padded={self.texels.size - n_in}, triangles={self.n_triangles})")

    # -- dense views ---------------------------------------------------------------------
    @cached_property
    def triangle(self) -> np.ndarray:
        """(S, S) int32 triangle index per texel; −1 outside every triangle and the padding."""
        out = np.full(self.size * self.size, -1, dtype=np.int32)
        out[self.texels] = self.texel_triangle
        return _frozen(out.reshape(self.size, self.size))

    @cached_property
    def barycentric(self) -> np.ndarray:
        """(S, S, 3) float32 barycentric coordinates (zeros where ``triangle`` is −1)."""
        return _frozen(self.scatter(self.texel_barycentric))

    @cached_property
    def inside(self) -> np.ndarray:
        """(S, S) bool: the texel centre lies inside a UV triangle."""
        out = np.zeros(self.size * self.size, dtype=bool)
        out[self.texels[self.texel_inside]] = True
        return _frozen(out.reshape(self.size, self.size))

    @cached_property
    def mask(self) -> np.ndarray:
        """(S, S) bool: the texel has a triangle (inside or padded)."""
        out = np.zeros(self.size * self.size, dtype=bool)
        out[self.texels] = True
        return _frozen(out.reshape(self.size, self.size))

    @property
    def padded(self) -> np.ndarray:
        """(S, S) bool: padding texels (a triangle assigned, centre outside it)."""
        return self.mask & ~self.inside

    # -- helpers ----------------------------------------------------------------------------
    def scatter(self, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """Dense (S, S, ...) map from per-texel ``values`` (N, ...), ``fill`` elsewhere."""
        values = np.asarray(values)
        shape = (self.size * self.size, *values.shape[1:])
        out = np.zeros(shape, dtype=values.dtype) if fill == 0 else np.full(shape, fill, dtype=values.dtype)
        out[self.texels] = values
        return out.reshape(self.size, self.size, *values.shape[1:])

    def gather(self, image: np.ndarray) -> np.ndarray:
        """Per-texel values (N, ...) of a dense (S, S, ...) map."""
        image = np.asarray(image)
        return image.reshape(self.size * self.size, *image.shape[2:])[self.texels]

    def interpolate(self, corner_values: np.ndarray) -> np.ndarray:
        """Barycentric interpolation of per-corner data: (F, 3, C) -> (N, C) float32."""
        v = np.take(np.asarray(corner_values, dtype=np.float32), self.texel_triangle, axis=0)  # (N, 3, C)
        b = self.texel_barycentric
        return v[:, 0] * b[:, 0:1] + v[:, 1] * b[:, 1:2] + v[:, 2] * b[:, 2:3]

    @property
    def nbytes(self) -> int:
        """Bytes held by the compact arrays."""
        return sum(getattr(self, name).nbytes for name in _COMPACT)


def rasterize_uv(model_or_uv, uv_triangles: np.ndarray | None = None, size: int = 1024,
                 padding: int | None = None, *, cache: bool = True) -> UVRaster:
    """Rasterise a UV layout: per texel, the covering triangle and its barycentric coordinates.

    Args:
        model_or_uv: a :class:`facegeo.MorphableModel` (any object with ``uv`` and
            ``uv_triangles``), or a (T, 2) array of UV coordinates in [0, 1]², origin bottom-left.
        uv_triangles: (F, 3) int indices into the UV array (only with an array; face-varying
            layouts with seams are fine).
        size: S, the map side in texels (1 ≤ S ≤ 16384).
        padding: seam padding in texels (default :func:`default_padding`: S/128, at least 2);
            0 for none; ≥ S fills the whole map.
        cache: reuse (and store) the result for this layout, size and padding: kept in the
            process and in the disk cache (:mod:`facegeo.layout_cache`), whose arrays are
            memory-mapped.
    Returns:
        A read-only :class:`UVRaster`. Rasterising the bundled ICT-FaceKit layout at S = 1024
        takes about 0.25 s; loading it from the disk cache a few milliseconds, and a call cached
        in the process returns at once.
    Raises:
        InputError: malformed UV coordinates or triangles, or a bad size.
    """
    if uv_triangles is None:
        if not (hasattr(model_or_uv, "uv") and hasattr(model_or_uv, "uv_triangles")):
            raise InputError("<array>", "uv_triangles", "a model with uv and uv_triangles, or UVs and (F, 3) uv_triangles",
                             type(model_or_uv).__name__)
        uv, tris = model_or_uv.uv, model_or_uv.uv_triangles
    else:
        uv, tris = model_or_uv, uv_triangles
    uv, tris = _check_layout(uv, tris)
    size = int(size)
    if not 1 <= size <= MAX_SIZE:
        raise InputError("<argument>", "size", f"an integer in [1, {MAX_SIZE}]", str(size))
    padding = default_padding(size) if padding is None else int(padding)
    if padding < 0:
        raise InputError("<argument>", "padding", "a number of texels ≥ 0", str(padding))
    padding = min(padding, size)
    digest = _layout_digest(uv, tris)
    if not cache:
        return _rasterize(uv, tris, size, padding, digest)
    key = (digest, size, padding)
    with _CACHE_LOCK:
        hit = _CACHE.get(key)
        if hit is not None:
            _CACHE.move_to_end(key)
            return hit
    raster = load_or_make(
        entry_folder(f"raster-{digest}-{size}-{padding}"),
        lambda arrays, meta: UVRaster(size, padding, meta["n_triangles"], *(arrays[name] for name in _COMPACT), key=digest,
                                      views={name: arrays[name] for name in DISK_VIEWS}),  # memory-mapped
        lambda: _rasterize(uv, tris, size, padding, digest),
        lambda made: ({name: getattr(made, name) for name in (*_COMPACT, *DISK_VIEWS)}, {"n_triangles": made.n_triangles}))
    with _CACHE_LOCK:
        _CACHE[key] = raster
        _CACHE.move_to_end(key)
        while len(_CACHE) > 1 and (len(_CACHE) > CACHE_ENTRIES or sum(r.nbytes for r in _CACHE.values()) > CACHE_BYTES):
            _CACHE.popitem(last=False)
    return raster


def clear_raster_cache() -> None:
    """Forget every cached :class:`UVRaster` (for timing cold runs)."""
    with _CACHE_LOCK:
        _CACHE.clear()


# ---------------------------------------------------------------------------------------- internals
def _check_layout(uv: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    uv = np.asarray(uv)
    tris = np.asarray(tris)
    if uv.ndim != 2 or uv.shape[1] != 2 or uv.dtype.kind not in "fiu":
        raise InputError("<array>", "uv", "a (T, 2) array of numbers", f"{uv.dtype} array of shape {uv.shape}")
    if not np.all(np.isfinite(uv)):
        raise InputError("<array>", "uv", "finite UV coordinates", f"{int(np.sum(~np.isfinite(uv)))} NaN/inf values")
    if tris.ndim != 2 or tris.shape[1] != 3 or tris.dtype.kind not in "iu":
        raise InputError("<array>", "uv_triangles", "an (F, 3) integer array", f"{tris.dtype} array of shape {tris.shape}")
    if tris.size and (tris.min() < 0 or tris.max() >= uv.shape[0]):
        raise InputError("<array>", "uv_triangles", f"indices in [0, {uv.shape[0]})", f"range [{tris.min()}, {tris.max()}]")
    return uv.astype(np.float64), tris.astype(np.int64)


def _layout_digest(uv: np.ndarray, tris: np.ndarray) -> str:
    h = hashlib.blake2b(digest_size=16)
    for a in (uv, tris):
        h.update(str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _rasterize(uv: np.ndarray, tris: np.ndarray, size: int, padding: int, key: str) -> UVRaster:
    S = size
    pts = uv_to_texel(uv[tris], S, S).astype(np.float64)  # (F, 3, 2) texel-grid coordinates
    parts = list(triangle_fragments(pts, S, S))
    if parts:
        pix = np.concatenate([p[0] for p in parts])
        tri = np.concatenate([p[1] for p in parts]).astype(np.int32)
        bary = np.concatenate([p[2] for p in parts]).astype(np.float32)
    else:
        pix, tri, bary = np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros((0, 3), np.float32)
    # overlapping UV triangles: the lowest triangle index wins (deterministic)
    tri_map = np.full(S * S, np.iinfo(np.int32).max, dtype=np.int32)
    np.minimum.at(tri_map, pix, tri)
    won = np.flatnonzero(tri_map[pix] == tri)
    where = np.full(S * S, -1, dtype=np.int32)
    where[pix[won]] = won
    inside = where >= 0
    tri_map = np.where(inside, tri_map, -1)
    texels = np.flatnonzero(inside)
    frag = where[texels]
    t_tri = tri[frag].astype(np.int64)
    t_bary = bary[frag]
    t_inside = np.ones(texels.size, dtype=bool)
    if padding > 0 and texels.size and texels.size < S * S:
        band = _padding_band(inside.reshape(S, S), padding).ravel()
        pad = np.flatnonzero(band)
        nearest = _nearest_inside(inside.reshape(S, S))[pad]
        ptri = tri_map[nearest].astype(np.int64)
        rows, cols = np.divmod(pad, S)
        centre = np.stack([cols + 0.5, rows + 0.5], axis=1)
        pbary = _closest_point_barycentric(pts[ptri], centre).astype(np.float32)
        texels = np.concatenate([texels, pad])
        order = np.argsort(texels, kind="stable")
        texels = texels[order]
        t_tri = np.concatenate([t_tri, ptri])[order]
        t_bary = np.concatenate([t_bary, pbary])[order]
        t_inside = np.concatenate([t_inside, np.zeros(pad.size, dtype=bool)])[order]
    return UVRaster(S, padding, tris.shape[0], texels, t_tri, t_bary, t_inside, key)


def _padding_band(inside: np.ndarray, padding: int) -> np.ndarray:
    """Texels within chessboard distance ``padding`` of an inside texel, minus the inside ones."""
    k = 2 * padding + 1
    grown = cv2.dilate(inside.astype(np.uint8), np.ones((k, k), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return (grown > 0) & ~inside


def _nearest_inside(inside: np.ndarray) -> np.ndarray:
    """(S·S,) flat index of a nearest inside texel for every texel (OpenCV's 5×5 L2 distance
    transform, within a fraction of a texel of the exact Euclidean nearest one nearby)."""
    src = (~inside).astype(np.uint8)  # zeros = inside texels = the seeds
    _, labels = cv2.distanceTransformWithLabels(src, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    seeds = np.flatnonzero(inside.ravel())  # label k (1-based) = k-th seed in raster order
    return seeds[labels.ravel() - 1]


def _closest_point_barycentric(tri_pts: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of the point of each triangle closest to ``p``.

    tri_pts: (K, 3, 2) corners; p: (K, 2). Returns (K, 3) float64, each ≥ 0 summing to 1.
    Degenerate triangles (segments or points) are handled by the edge projections.
    """
    a, b, c = tri_pts[:, 0], tri_pts[:, 1], tri_pts[:, 2]
    # unclamped barycentrics (valid when the projection is inside)
    v0, v1, v2 = b - a, c - a, p - a
    d00 = (v0 * v0).sum(1)
    d01 = (v0 * v1).sum(1)
    d11 = (v1 * v1).sum(1)
    d20 = (v2 * v0).sum(1)
    d21 = (v2 * v1).sum(1)
    den = d00 * d11 - d01 * d01
    with np.errstate(divide="ignore", invalid="ignore"):
        lb = (d11 * d20 - d01 * d21) / den
        lc = (d00 * d21 - d01 * d20) / den
    la = 1.0 - lb - lc
    best = np.stack([la, lb, lc], axis=1)
    ok = np.isfinite(best).all(1) & (best >= 0).all(1)
    best_d = np.where(ok, 0.0, np.inf)
    best = np.where(ok[:, None], best, 0.0)
    corners = (a, b, c)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        e = corners[j] - corners[i]
        ee = (e * e).sum(1)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.clip(((p - corners[i]) * e).sum(1) / ee, 0.0, 1.0)
        t = np.where(ee > 0, t, 0.0)
        q = corners[i] + t[:, None] * e
        d = ((p - q) ** 2).sum(1)
        take = d < best_d
        w = np.zeros((p.shape[0], 3))
        w[:, i] = 1.0 - t
        w[:, j] = t
        best = np.where(take[:, None], w, best)
        best_d = np.where(take, d, best_d)
    return best


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a
