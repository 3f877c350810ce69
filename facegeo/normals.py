"""Vertex normals of a triangle mesh: one rule, a NumPy function and its differentiable torch twin.

The rule (used everywhere: fitting, UV maps and MikkTSpace, displacement baking, exporters, the
preview): a vertex's normal is the normalised sum of the cross products ``(b − a) × (c − a)`` of
the counter-clockwise triangles that use it (area-weighted face normals). A vertex whose sum has
no length (no triangle uses it, its triangles have no area, or opposite triangles cancel; length
≤ 1e-12 × the mesh's longest sum) takes the normalised sum of its neighbours' normals, ring by
ring (at most :data:`FALLBACK_RINGS` rings, for clusters of degenerate triangles), and +Z (out of
the face, DESIGN.md) if that has no length either. So every normal is a finite unit vector: the
one rule that never returns zero vectors or NaN, which the exporters and displacement need (a
zero normal moves nothing and breaks tangent frames), while it changes nothing on a clean mesh.

:func:`vertex_normals` accumulates in float64 (the reference); :func:`vertex_normals_torch` computes
in the input's dtype and is differentiable (the fit and the regressor's photometric term);
``tests/test_normals.py`` checks that the two agree.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the twin imports torch when called: the NumPy rule (the fit, the exporters) never loads it
    import torch

__all__ = ["vertex_normals", "vertex_normals_torch", "FALLBACK_NORMAL", "FALLBACK_RINGS"]

#: The normal of a vertex with no usable triangle and no usable neighbour: +Z, out of the face.
FALLBACK_NORMAL = (0.0, 0.0, 1.0)
#: How many rings of neighbours a vertex without a normal of its own looks through.
FALLBACK_RINGS = 3
#: A sum shorter than this fraction of the mesh's longest sum counts as having no length.
_RELATIVE_EPS = 1e-12


def _edges(triangles: np.ndarray) -> np.ndarray:
    """(3F, 2) directed edges (a, b), (b, c), (c, a) of the triangles."""
    return np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])


def _face_normals(planes: list[np.ndarray], f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The x, y and z components of ``(b − a) × (c − a)`` for the (F, 3) triangles ``f`` of
    vertices given as their x, y and z ``planes``, each (V,) or (V, B) float64 (B meshes on the
    same triangles): three (F,) or (F, B) float64 arrays. ``np.cross``'s products and differences
    (the same bits), on contiguous per-component arrays instead of its (F, 3) temporaries (half
    the time; a third in a fresh process, whose every new page is a fault)."""
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    edges = []
    for plane in planes:  # the edges b − a and c − a: each corner gathered once, differences in place
        first, u, w = plane[a], plane[b], plane[c]
        u -= first
        w -= first
        edges.append((u, w))
    (ux, wx), (uy, wy), (uz, wz) = edges
    normal = []
    for p, q, r, t in ((uy, wz, uz, wy), (uz, wx, ux, wz), (ux, wy, uy, wx)):  # p·q − r·t
        product = p * q
        product -= r * t
        normal.append(product)
    return normal[0], normal[1], normal[2]


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Unit vertex normals by the module's rule.

    Args:
        vertices: (V, 3) positions (any float dtype, any units), or (B, V, 3): B meshes on the
            same triangles (e.g. a mesh's blendshapes), computed together.
        triangles: (F, 3) counter-clockwise vertex indices.
    Returns:
        (V, 3) or (B, V, 3) float64 unit vectors.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if v.ndim == 3:
        return _batched_vertex_normals(v, f)
    face_n = _face_normals([v[:, 0], v[:, 1], v[:, 2]], f)  # 2 × area × unit normal, one (F,) array a component
    corners = f.ravel()
    n = np.stack([np.bincount(corners, weights=np.repeat(component, 3), minlength=len(v)) for component in face_n], axis=1)
    length = np.linalg.norm(n, axis=1)
    scale = np.max(length) if len(length) else 0.0
    bad = length <= _RELATIVE_EPS * max(scale, 1e-300)
    if not bad.any():
        return n / length[:, None]
    import scipy.sparse as sp  # only for meshes with such vertices

    unit = np.zeros_like(n)
    unit[~bad] = n[~bad] / length[~bad, None]
    e = _edges(f)
    rows, cols = np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]])
    adjacency = sp.csr_matrix((np.ones(2 * len(e)), (rows, cols)), shape=(len(v), len(v)))
    for _ in range(FALLBACK_RINGS):
        neighbour = adjacency[np.flatnonzero(bad)] @ unit
        nl = np.linalg.norm(neighbour, axis=1)
        good = nl > 1e-12
        idx = np.flatnonzero(bad)[good]
        unit[idx] = neighbour[good] / nl[good, None]
        bad[idx] = False
        if not bad.any():
            break
    unit[bad] = FALLBACK_NORMAL
    return unit


def _batched_vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """:func:`vertex_normals` of (B, V, 3) meshes: the face normals' sums by one sparse product,
    and the same fallback (neighbours' normals, ring by ring) for all meshes at once."""
    import scipy.sparse as sp

    b, n = v.shape[:2]
    # the cross products per component as (F, B) arrays: the columns a triangle's corners gather
    # are whole contiguous rows of each (V, B) plane, not strided thirds of (F, B, 3) ones
    planes = [np.ascontiguousarray(v[..., k].T) for k in range(3)]
    face_n = _face_normals(planes, f)
    incidence = sp.csr_matrix((np.ones(f.size), (f.ravel(), np.repeat(np.arange(len(f)), 3))), shape=(n, len(f)))
    # each vertex's sum over its triangles, in the CSR order, whatever the columns: (V, B, 3) as before
    sums = np.stack([incidence @ component for component in face_n], axis=-1).transpose(1, 0, 2)
    length = np.sqrt(np.einsum("bvc,bvc->bv", sums, sums))
    scale = length.max(axis=1, keepdims=True) if n else length
    bad = length <= _RELATIVE_EPS * np.maximum(scale, 1e-300)
    unit = np.where(bad[..., None], 0.0, sums / np.where(bad, 1.0, length)[..., None])
    if not bad.any():
        return unit
    e = _edges(f)  # the fallback of vertex_normals, ring by ring, for all meshes at once
    adjacency = sp.csr_matrix((np.ones(2 * len(e)), (np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]]))),
                              shape=(n, n))
    for _ in range(FALLBACK_RINGS):
        rows = np.flatnonzero(bad.any(axis=0))
        neighbour = (adjacency[rows] @ unit.transpose(1, 0, 2).reshape(n, 3 * b)).reshape(len(rows), b, 3).transpose(1, 0, 2)
        nl = np.sqrt(np.einsum("brc,brc->br", neighbour, neighbour))
        fixed = bad[:, rows] & (nl > 1e-12)
        block = unit[:, rows]
        block[fixed] = neighbour[fixed] / nl[fixed][:, None]
        unit[:, rows] = block
        bad[:, rows] &= ~fixed
        if not bad.any():
            return unit
    unit[bad] = FALLBACK_NORMAL
    return unit


def vertex_normals_torch(vertices: torch.Tensor, triangles: torch.Tensor | np.ndarray) -> torch.Tensor:
    """The torch twin of :func:`vertex_normals`: (..., V, 3) vertices (any batch shape) and (F, 3)
    triangles -> (..., V, 3) unit normals in the vertices' dtype, differentiable.

    The fallback for vertices without a normal of their own (a data-dependent branch, taken only
    when such a vertex exists) is the same as :func:`vertex_normals`'s, per batch element.
    """
    import torch

    # (a read-only array, e.g. the default model's memory-mapped triangles, is copied: torch warns on sharing it)
    tri = triangles.long() if isinstance(triangles, torch.Tensor) else torch.as_tensor(np.require(triangles, requirements="W"), dtype=torch.long)
    a, b, c = vertices[..., tri[:, 0], :], vertices[..., tri[:, 1], :], vertices[..., tri[:, 2], :]
    face_n = torch.cross(b - a, c - a, dim=-1)
    normals = torch.zeros_like(vertices)
    for k in range(3):
        normals = normals.index_add(-2, tri[:, k], face_n)
    unit = torch.nn.functional.normalize(normals, dim=-1, eps=1e-12)
    length = torch.linalg.vector_norm(normals, dim=-1)
    scale = length.amax(dim=-1, keepdim=True) if length.shape[-1] else length
    bad = length <= _RELATIVE_EPS * scale.clamp_min(1e-300)
    if not bool(bad.any()):
        return unit
    unit = torch.where(bad[..., None], torch.zeros_like(unit), unit)
    e = torch.from_numpy(_edges(tri.numpy()))
    src, dst = torch.cat([e[:, 0], e[:, 1]]), torch.cat([e[:, 1], e[:, 0]])
    for _ in range(FALLBACK_RINGS):
        neighbour = torch.zeros_like(unit).index_add(-2, src, unit[..., dst, :])
        nl = torch.linalg.vector_norm(neighbour, dim=-1)
        fixed = bad & (nl > 1e-12)
        unit = torch.where(fixed[..., None], neighbour / nl.clamp_min(1e-12)[..., None], unit)
        bad = bad & ~fixed
        if not bool(bad.any()):
            return unit
    fallback = torch.tensor(FALLBACK_NORMAL, dtype=unit.dtype).expand_as(unit)
    return torch.where(bad[..., None], fallback, unit)
