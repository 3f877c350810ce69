"""Build the :class:`TextureContext` of a fit: its geometry, lighting and priors in UV space."""

from __future__ import annotations

import numpy as np
import torch
import scipy.sparse as sp
from scipy.spatial import cKDTree

from facegeo.colour import linear_to_srgb
from facegeo.fitting import Fit
from facegeo.morphable_model import MorphableModel
from facegeo.skin_mask import skin_vertex_mask, vertex_regions
from facegeo.texturing.backend import SurfaceOperators, TextureContext
from facegeo.uv import GeometryMaps, UVRaster, geometry_maps
from facegeo.uv.texels import nearest_texel

__all__ = ["build_context", "mirror_vertices", "surface_operators"]

#: A vertex has a mirror partner when the reflection x → −x of it lies this close to a vertex.
MIRROR_TOLERANCE_MM = 1.0


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
    """The texel <-> vertex maps and the edge Laplacian of ``model`` on ``raster``'s layout."""
    V = model.n_vertices
    corners = np.asarray(model.triangles)[raster.texel_triangle]  # (N, 3) vertex of each corner
    n = len(raster.texels)
    rows = np.repeat(np.arange(n), 3)
    interpolation = sp.csr_matrix((raster.texel_barycentric.astype(np.float64).ravel(), (rows, corners.ravel())), shape=(n, V))
    tri = np.asarray(model.triangles)
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    adjacency = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(V, V)).tocsr()
    adjacency = ((adjacency + adjacency.T) > 0).astype(np.float64)
    laplacian = sp.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency
    return SurfaceOperators(np.asarray(raster.texels), interpolation, laplacian.tocsr())


def build_context(model: MorphableModel, fit: Fit, raster: UVRaster, camera_maps: GeometryMaps | None = None,
                  white_reference: np.ndarray | None = None) -> TextureContext:
    """The texture stage's view of ``fit`` at the raster's size S (see :class:`TextureContext`).

    ``camera_maps``: the geometry maps of ``fit.vertices`` on ``raster`` if already computed
    (e.g. for the unwrap); their normals are the context's camera-space normals.
    ``white_reference``: the photo's white references (:attr:`facegeo.skin_mask.SkinMask.white_reference`)."""
    size = raster.size
    tri = model.triangles
    cover = np.asarray(raster.inside)
    mask = np.asarray(raster.mask)

    def to_uv(per_vertex: np.ndarray) -> np.ndarray:
        per_vertex = np.asarray(per_vertex, dtype=np.float32).reshape(model.n_vertices, -1)
        return raster.scatter(raster.interpolate(per_vertex[tri]))

    position = to_uv(fit.shape_vertices)
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

    # the mirror texel: interpolate the UVs of the corners' mirror vertices
    partner = mirror_vertices(model)
    vertex_uv = _per_vertex_uv(model)
    corner_ok = (partner[tri] >= 0).all(axis=1)
    mirror_uv = raster.interpolate(vertex_uv[np.maximum(partner, 0)][tri])
    ok = corner_ok[raster.texel_triangle] & raster.texel_inside
    rows, cols = (a.astype(np.int32) for a in nearest_texel(mirror_uv, size, size))
    ok &= cover[rows, cols]
    mirror = raster.scatter(np.where(ok[:, None], np.stack([rows, cols], 1), -1).astype(np.int32), fill=-1)

    albedo = model.albedo(torch.from_numpy(fit.beta)).numpy() if model.n_tex else model.mean_albedo
    mean_texture = linear_to_srgb(to_uv(np.clip(albedo, 0.0, 1.0)))
    regions = {name: to_uv(m)[..., 0] for name, m in vertex_regions(model).items()}
    skin = to_uv(skin_vertex_mask(model).astype(np.float32))[..., 0]
    return TextureContext(
        coverage=cover,
        position=position.astype(np.float32),
        normal_camera=normal_camera.astype(np.float32),
        texel_size_mm=texel,
        gamma=np.asarray(fit.gamma, dtype=np.float32),
        mean_texture=mean_texture.astype(np.float32),
        mirror=mirror,
        regions=regions,
        skin=skin.astype(np.float32),
        surface=surface_operators(model, raster),
        white_reference=None if white_reference is None else np.asarray(white_reference, np.float64),
    )
