"""Build the :class:`TextureContext` of a fit: its geometry, lighting and priors in UV space.

What depends only on the model and the UV raster (the surface operators, the mirror map, the
region and skin masks, the mean texture of a model without an albedo basis) is the
:class:`LayoutPriors` of :func:`layout_priors`, computed once per model, raster and code version
and kept on disk (:mod:`facegeo.layout_cache`; later processes memory-map it) and in the
process, shared, read-only, by every context built on them (batch mode reuses it across photos).
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from facegeo.colour import linear_to_srgb
from facegeo.fitting import Fit
from facegeo.layout_cache import entry_folder, load_or_make
from facegeo.morphable_model import MorphableModel
from facegeo.skin_mask import skin_vertex_mask, vertex_regions
from facegeo.texturing.backend import SurfaceOperators, TextureContext
from facegeo.uv import GeometryMaps, UVRaster, geometry_maps
from facegeo.uv.texels import nearest_texel

__all__ = ["build_context", "mirror_vertices", "surface_operators", "layout_priors", "LayoutPriors"]

#: A vertex has a mirror partner when the reflection x → −x of it lies this close to a vertex.
MIRROR_TOLERANCE_MM = 1.0
#: :class:`LayoutPriors` kept per process (least recently used dropped first); one is ~70 MB at 1K.
LAYOUT_CACHE_ENTRIES = 2

_LAYOUT_CACHE: OrderedDict[tuple[str, str, int, int], LayoutPriors] = OrderedDict()
_LAYOUT_LOCK = threading.Lock()


def mirror_vertices(model: MorphableModel) -> np.ndarray:
    """(V,) int64 index of each vertex's left/right mirror on the mean shape, −1 where the
    reflected point is farther than :data:`MIRROR_TOLERANCE_MM` from every vertex."""
    reflected = model.mean_shape * np.array([-1.0, 1.0, 1.0], dtype=np.float32)
    distance, index = cKDTree(model.mean_shape).query(reflected)
    return np.where(distance <= MIRROR_TOLERANCE_MM, index, -1).astype(np.int64)


def _per_vertex_uv(model: MorphableModel) -> np.ndarray:
    """(V, 2) one UV per vertex (the first corner that uses it; seams pick one side)."""
    uv = np.zeros((model.n_vertices, 2), np.float32)
    uv[model.triangles[::-1].ravel()] = model.uv[model.uv_triangles[::-1].ravel()]
    return uv


def surface_operators(model: MorphableModel, raster: UVRaster) -> SurfaceOperators:
    """The texel <-> vertex maps and the edge Laplacian of ``model`` on ``raster``'s layout.

    The interpolation matrix is assembled directly in canonical CSR form (each row's three
    corners sorted by vertex index; a corner repeated in a degenerate triangle summed), the form
    SciPy's COO → CSR conversion gives, without its sort of all 3N entries."""
    V = model.n_vertices
    tri = np.asarray(model.triangles)
    corners = tri.astype(np.int32)[raster.texel_triangle]  # (N, 3) vertex of each corner
    n = len(raster.texels)
    weights = raster.texel_barycentric.astype(np.float64)
    a, b, c = corners.T
    if n and ((a == b) | (b == c) | (a == c)).any():  # a degenerate triangle: SciPy sums the repeated corner
        rows = np.repeat(np.arange(n), 3)
        interpolation = sp.csr_matrix((weights.ravel(), (rows, corners.ravel())), shape=(n, V))
    else:
        ab, bc, ac = a > b, b > c, a > c  # each corner's place in its row (0 = the lowest vertex)
        rank = np.stack([np.add(ab, ac, dtype=np.intp), np.add(~ab, bc, dtype=np.intp), np.add(~ac, ~bc, dtype=np.intp)], axis=1)
        slot = (np.arange(n)[:, None] * 3 + rank).ravel()
        columns, values = np.empty(3 * n, np.int32), np.empty(3 * n, np.float64)
        columns[slot], values[slot] = corners.ravel(), weights.ravel()
        interpolation = sp.csr_matrix((values, columns, np.arange(0, 3 * n + 1, 3, dtype=np.int32)), shape=(n, V))
        interpolation.has_canonical_format = True
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    adjacency = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(V, V)).tocsr()
    adjacency = ((adjacency + adjacency.T) > 0).astype(np.float64)
    laplacian = sp.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency
    return SurfaceOperators(np.asarray(raster.texels), interpolation, laplacian.tocsr())


@dataclass(frozen=True, eq=False)
class LayoutPriors:
    """The parts of a :class:`TextureContext` that depend only on the model and the UV raster
    (S × S texels); every array is read-only (shared between contexts).

    coverage: (S, S) bool, texels inside the layout (``raster.inside``).
    mirror: (S, S, 2) int32 (row, col) of each texel's mirror texel, (−1, −1) where none.
    regions: name -> (S, S) float32 soft region masks (:func:`facegeo.skin_mask.vertex_regions`).
    skin: (S, S) float32 skin mask (:func:`facegeo.skin_mask.skin_vertex_mask` in UV).
    surface: the :class:`SurfaceOperators` of the model on the raster.
    mean_texture: (S, S, 3) float32 sRGB mean albedo in UV for a model without an albedo basis
        (``model.n_tex == 0``), else None (it depends on the fit's β).
    """

    coverage: np.ndarray
    mirror: np.ndarray
    regions: dict[str, np.ndarray]
    skin: np.ndarray
    surface: SurfaceOperators
    mean_texture: np.ndarray | None


def _to_uv(model: MorphableModel, raster: UVRaster, per_vertex: np.ndarray) -> np.ndarray:
    """(V[, C]) vertex values -> (S, S, C) float32 map interpolated on ``raster`` (0 elsewhere)."""
    per_vertex = np.asarray(per_vertex, dtype=np.float32).reshape(model.n_vertices, -1)
    return raster.scatter(raster.interpolate(per_vertex[model.triangles]))


def _model_digest(model: MorphableModel) -> str:
    """A digest of the model arrays the layout priors are computed from."""
    h = hashlib.blake2b(digest_size=16)
    for a in (model.mean_shape, model.triangles, model.uv, model.uv_triangles, model.face_mask, model.landmark_indices,
              model.mean_albedo):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype}{a.shape}".encode())
        h.update(a.tobytes())
    h.update(str(model.n_tex).encode())
    return h.hexdigest()


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def _compute_layout_priors(model: MorphableModel, raster: UVRaster) -> LayoutPriors:
    size = raster.size
    tri = model.triangles
    cover = np.asarray(raster.inside)
    # the mirror texel: interpolate the UVs of the corners' mirror vertices
    partner = mirror_vertices(model)
    vertex_uv = _per_vertex_uv(model)
    corner_ok = (partner[tri] >= 0).all(axis=1)
    mirror_uv = raster.interpolate(vertex_uv[np.maximum(partner, 0)][tri])
    ok = corner_ok[raster.texel_triangle] & raster.texel_inside
    rows, cols = (a.astype(np.int32) for a in nearest_texel(mirror_uv, size, size))
    ok &= cover[rows, cols]
    mirror = raster.scatter(np.where(ok[:, None], np.stack([rows, cols], 1), -1).astype(np.int32), fill=-1)
    # the region masks and the skin mask in one interpolation (each channel's values as on its own)
    per_vertex = vertex_regions(model)
    maps = _to_uv(model, raster, np.stack([*per_vertex.values(), skin_vertex_mask(model).astype(np.float32)], axis=1))
    regions = {name: _read_only(np.ascontiguousarray(maps[..., k])) for k, name in enumerate(per_vertex)}
    skin = maps[..., -1]
    mean_texture = None
    if not model.n_tex:
        mean_texture = _read_only(linear_to_srgb(_to_uv(model, raster, np.clip(model.mean_albedo, 0.0, 1.0))).astype(np.float32))
    return LayoutPriors(coverage=cover, mirror=_read_only(mirror), regions=regions, skin=_read_only(np.ascontiguousarray(skin, np.float32)),
                        surface=surface_operators(model, raster), mean_texture=mean_texture)


_SPARSE = ("interpolation", "laplacian")  # the CSR matrices of SurfaceOperators


def _priors_arrays(priors: LayoutPriors) -> tuple[dict[str, np.ndarray], dict[str, object]]:
    """The arrays and the JSON meta that :func:`_rebuilt_priors` rebuilds ``priors`` from:
    the dense maps (the regions stacked, (R, S, S)), each CSR matrix as ``<name>_data``,
    ``_indices`` and ``_indptr`` with its shape and canonical-format flag; the coverage and the
    texels are the raster's own."""
    arrays = {"mirror": priors.mirror, "skin": priors.skin, "regions": np.stack(list(priors.regions.values()))}
    if priors.mean_texture is not None:
        arrays["mean_texture"] = priors.mean_texture
    meta: dict[str, object] = {"regions": list(priors.regions)}
    for name in _SPARSE:
        matrix = getattr(priors.surface, name)
        arrays.update({f"{name}_{part}": getattr(matrix, part) for part in ("data", "indices", "indptr")})
        meta[name] = {"shape": list(matrix.shape), "canonical": bool(matrix.has_canonical_format)}
    return arrays, meta


def _rebuilt_priors(arrays: dict[str, np.ndarray], meta: dict[str, object], model: MorphableModel,
                    raster: UVRaster) -> LayoutPriors | None:
    """The priors :func:`_priors_arrays` stored (arrays memory-mapped, the same dtypes, shapes and
    sparse formats as :func:`_compute_layout_priors` gives), or None where SciPy would narrow a
    stored index dtype (not the matrix that was stored)."""
    sparse = {}
    for name in _SPARSE:
        parts = tuple(arrays[f"{name}_{part}"] for part in ("data", "indices", "indptr"))
        matrix = sp.csr_matrix(parts, shape=tuple(meta[name]["shape"]))
        if any(m.dtype != a.dtype for m, a in zip((matrix.data, matrix.indices, matrix.indptr), parts)):
            return None
        matrix.has_canonical_format = meta[name]["canonical"]
        sparse[name] = matrix
    regions = dict(zip(meta["regions"], arrays["regions"], strict=True))
    return LayoutPriors(coverage=raster.inside, mirror=arrays["mirror"], regions=regions, skin=arrays["skin"],
                        surface=SurfaceOperators(np.asarray(raster.texels), sparse["interpolation"], sparse["laplacian"]),
                        mean_texture=None if model.n_tex else arrays["mean_texture"])


def layout_priors(model: MorphableModel, raster: UVRaster) -> LayoutPriors:
    """The :class:`LayoutPriors` of ``model`` on ``raster``, keyed by a digest of the model's
    arrays and the raster's layout, size and padding: kept per process (the last
    :data:`LAYOUT_CACHE_ENTRIES`) and on disk (:mod:`facegeo.layout_cache`, memory-mapped; ~0.4 s
    to compute at S = 1024, milliseconds to load)."""
    digest = _model_digest(model)
    key = (digest, raster.key, raster.size, raster.padding)
    with _LAYOUT_LOCK:
        hit = _LAYOUT_CACHE.get(key)
        if hit is not None:
            _LAYOUT_CACHE.move_to_end(key)
            return hit
    priors = load_or_make(entry_folder(f"priors-{digest}-{raster.key}-{raster.size}-{raster.padding}"),
                          lambda arrays, meta: _rebuilt_priors(arrays, meta, model, raster),
                          lambda: _compute_layout_priors(model, raster), _priors_arrays)
    with _LAYOUT_LOCK:
        _LAYOUT_CACHE[key] = priors
        _LAYOUT_CACHE.move_to_end(key)
        while len(_LAYOUT_CACHE) > LAYOUT_CACHE_ENTRIES:
            _LAYOUT_CACHE.popitem(last=False)
    return priors


def build_context(model: MorphableModel, fit: Fit, raster: UVRaster, camera_maps: GeometryMaps | None = None,
                  white_reference: np.ndarray | None = None) -> TextureContext:
    """The texture stage's view of ``fit`` at the raster's size S (see :class:`TextureContext`).

    ``camera_maps``: the geometry maps of ``fit.vertices`` on ``raster`` if already computed
    (e.g. for the unwrap); their normals are the context's camera-space normals.
    ``white_reference``: the photo's white references (:attr:`facegeo.skin_mask.SkinMask.white_reference`)."""
    layout = layout_priors(model, raster)
    cover = layout.coverage
    mask = np.asarray(raster.mask)
    position = _to_uv(model, raster, fit.shape_vertices)
    if camera_maps is None:
        camera_maps = geometry_maps(fit.vertices, model, raster, tangents=False)
    normal_camera = np.where(mask[..., None], camera_maps.normal, 0.0)

    # texel size on the surface: |∂P/∂column| and |∂P/∂row| (rows run towards −v)
    texel = np.stack(
        [np.linalg.norm(np.gradient(position, axis=1), axis=-1), np.linalg.norm(np.gradient(position, axis=0), axis=-1)],
        axis=-1,
    ).astype(np.float32)
    median = np.median(texel[cover], axis=0) if cover.any() else np.ones(2, np.float32)
    texel = np.where(cover[..., None] & (texel > 0), texel, median)  # seams/borders: the typical size

    mean_texture = layout.mean_texture
    if mean_texture is None:
        albedo = model.albedo_numpy(fit.beta)
        mean_texture = linear_to_srgb(_to_uv(model, raster, np.clip(albedo, 0.0, 1.0)))
    return TextureContext(
        coverage=cover,
        position=position.astype(np.float32),
        normal_camera=normal_camera.astype(np.float32),
        texel_size_mm=texel,
        gamma=np.asarray(fit.gamma, dtype=np.float32),
        mean_texture=mean_texture.astype(np.float32, copy=False),
        mirror=layout.mirror,
        regions=dict(layout.regions),
        skin=layout.skin,
        surface=layout.surface,
        white_reference=None if white_reference is None else np.asarray(white_reference, np.float64),
        position_camera=np.where(mask[..., None], camera_maps.position, 0.0).astype(np.float32),
        vertices_camera=np.asarray(fit.vertices, np.float32),
        triangles=np.asarray(model.triangles, np.int64),
    )
