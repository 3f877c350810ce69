"""Loop subdivision of a triangle mesh that carries face-varying UVs.

What the libraries do and what is written here
----------------------------------------------
The geometry is subdivided with libigl's Loop subdivision matrices (``igl.loop_matrix``: Loop's
original weights, β = (5/8 − (3/8 + ¼·cos(2π/n))²)/n, cubic B-spline rules on boundary curves).
None of the installed libraries subdivides a *face-varying* UV layer: ``igl.loop``,
``trimesh.remesh.subdivide_loop`` and ``pymeshlab``'s Loop filter subdivide one attribute set
per vertex, and pymeshlab interpolates wedge texture coordinates linearly; OpenSubdiv has no
maintained Python binding on PyPI. So the UV layer is subdivided here, with the same library:
``igl.loop_matrix`` is run on the UV topology (``uv_triangles``), whose boundary edges are the
mesh boundary plus both sides of every UV seam. libigl builds the four children of every face
in a fixed corner pattern, so child corner k of child face j of the geometry and of the UV mesh
are the same wedge; this is checked at every level.

Rules (the surface rule wherever the UV layer can follow it):

* new UV on an edge: the Loop edge rule (3/8, 3/8, 1/8, 1/8) of the UV mesh; on a seam or
  boundary edge the midpoint (the boundary edge rule, as for the geometry's boundary edges);
* UV of an old vertex: the geometry's stencil, with the same neighbours and weights, whenever
  the UV neighbourhood reproduces it (every vertex inside a chart, and vertices on the mesh's own
  boundary away from seams, where both use the B-spline boundary rule); otherwise - on a seam,
  where the geometry's stencil reaches into the other chart, and at seam junctions and
  non-manifold corners - the UV is kept (a sharp, linear seam: OpenSubdiv's "linear boundaries"
  on seams only).

So the geometry is watertight (it never sees the seams), the two sides of a seam stay on the
coarse seam polyline of their charts (the texture cannot swim across a seam or into the chart
padding), and inside a chart a vertex's UV is the same affine combination of coarse UVs as its
position is of coarse positions. ``uv_interpolation="linear"`` gives midpoints everywhere
(OpenSubdiv's "linear all") instead.

What libigl does not handle is handled before it is called: faces that repeat a vertex index
are dropped (they have no area; libigl crashes on them), UV indices shared by corners of
different vertices are split, edges shared by more than two faces or traversed twice in the same
direction (inconsistent orientation; libigl crashes on both) are rejected, libigl is called on
the referenced vertices only (it reads out of bounds otherwise) and unreferenced or
non-manifold vertices (a bow tie) are kept in place.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from facegeo.asset import Asset
from facegeo.errors import InputError
from facegeo.export.facevarying import FaceVaryingMesh, as_face_varying

__all__ = ["subdivide", "subdivide_arrays", "subdivide_with_operators", "apply_operators", "UV_INTERPOLATIONS", "MAX_LEVEL"]

#: Accepted ``uv_interpolation`` values.
UV_INTERPOLATIONS = ("surface", "linear")
#: Highest level accepted (level 5 of the ICT model is 11.4 M vertices).
MAX_LEVEL = 6


def subdivide(mesh: Asset | FaceVaryingMesh, level: int, *, uv_interpolation: str = "surface") -> Asset | FaceVaryingMesh:
    """Loop-subdivide ``mesh`` ``level`` times, UV layer included.

    ``mesh``: an :class:`~facegeo.asset.Asset` (returns an Asset with the same maps, constants
    and name; ``metadata["subdivision_level"]`` is increased by ``level``) or a
    :class:`~facegeo.export.facevarying.FaceVaryingMesh` (returns one; a Trimesh goes through
    :func:`~facegeo.export.facevarying.from_trimesh` and back with ``to_trimesh``). Each level multiplies the triangles by
    four; level 0 returns the mesh unchanged. See the module text for the rules.

    Raises:
        InputError: level outside [0, MAX_LEVEL], an unknown ``uv_interpolation``, an edge shared
            by more than two triangles, or malformed arrays.
    """
    fv = as_face_varying(mesh)
    v, f, uv, ut = subdivide_arrays(fv.vertices, fv.triangles, fv.uv, fv.uv_triangles, level, uv_interpolation=uv_interpolation)
    if isinstance(mesh, Asset):
        if level == 0:
            return mesh
        metadata = dict(mesh.metadata)
        metadata["subdivision_level"] = int(metadata.get("subdivision_level", 0)) + int(level)
        return Asset(v, f, uv, ut, maps=dict(mesh.maps), constants=dict(mesh.constants), name=mesh.name, metadata=metadata)
    return FaceVaryingMesh(v, f, uv, ut)


def subdivide_arrays(
    vertices: np.ndarray,
    triangles: np.ndarray,
    uv: np.ndarray | None,
    uv_triangles: np.ndarray | None,
    level: int,
    *,
    uv_interpolation: str = "surface",
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """:func:`subdivide` on arrays: (V, 3) mm, (F, 3), (T, 2) or None, (F, 3) or None ->
    the subdivided ``(vertices float64, triangles int64, uv float64 | None, uv_triangles | None)``."""
    v, f, uv_, ut, _ = subdivide_with_operators(vertices, triangles, uv, uv_triangles, level, uv_interpolation=uv_interpolation)
    return v, f, uv_, ut


def subdivide_with_operators(
    vertices: np.ndarray,
    triangles: np.ndarray,
    uv: np.ndarray | None,
    uv_triangles: np.ndarray | None,
    level: int,
    *,
    uv_interpolation: str = "surface",
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, list[sp.csr_matrix]]:
    """:func:`subdivide_arrays` plus the geometry's subdivision operators, one sparse matrix per
    level (level i maps the V_i values of level i to the V_(i+1) of level i+1; empty at level 0).
    Loop subdivision is linear in the vertex positions, so any per-vertex quantity that moves
    with the surface (a blendshape's displacement, a normal's change) is subdivided exactly by
    :func:`apply_operators` with the same matrices."""
    if isinstance(level, bool) or not isinstance(level, (int, np.integer)) or not 0 <= level <= MAX_LEVEL:
        raise InputError("<subdivide>", "level", f"an integer in [0, {MAX_LEVEL}]", repr(level))
    if uv_interpolation not in UV_INTERPOLATIONS:
        raise InputError("<subdivide>", "uv_interpolation", f"one of {', '.join(UV_INTERPOLATIONS)}", repr(uv_interpolation))
    fv = FaceVaryingMesh(vertices, triangles, uv, uv_triangles)
    v, f, uv_, ut = fv.vertices, fv.triangles, fv.uv, fv.uv_triangles
    operators: list[sp.csr_matrix] = []
    if level == 0:
        return v, f, uv_, ut, operators
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])
    if not keep.all():
        f = f[keep]
        ut = ut[keep] if ut is not None else None
        if len(f) == 0:
            raise InputError("<subdivide>", "triangles", "at least one triangle with three distinct vertices", "none")
    _check_manifold_edges(f)
    if ut is not None:
        uv_, ut = _split_shared_uvs(uv_, f, ut)
    for _ in range(level):
        s_geo, nf = _loop_matrix(f, len(v))
        _check_child_pattern(f, nf)
        if ut is not None:
            s_uv, nft = _loop_matrix(ut, len(uv_))
            _check_child_pattern(ut, nft)
            uv_of_vertex = np.empty(len(uv_), dtype=np.int64)  # UV index -> its one geometry vertex
            uv_of_vertex[ut.ravel()] = f.ravel()
            if uv_interpolation == "surface":
                s_uv = _surface_uv_rows(s_geo, s_uv, uv_of_vertex, len(v))
            else:
                s_uv = _linear_uv_rows(s_uv, len(uv_))
            uv_ = s_uv @ uv_
            ut = nft
        v = s_geo @ v
        f = nf
        operators.append(s_geo)
    return v, f, uv_, ut, operators


def apply_operators(operators: list[sp.csr_matrix], values: np.ndarray) -> np.ndarray:
    """(V, C) per-vertex values of the coarse mesh -> (V_L, C) on the subdivided one, through the
    operators of :func:`subdivide_with_operators` (float64)."""
    out = np.asarray(values, dtype=np.float64)
    for s in operators:
        out = s @ out
    return out


# -- internals ---------------------------------------------------------------------------------


def _edges(f: np.ndarray) -> np.ndarray:
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    return np.sort(e, axis=1)


def _check_manifold_edges(f: np.ndarray) -> None:
    """libigl needs an oriented manifold: no edge in more than two triangles, and the two
    triangles of an edge traverse it in opposite directions (it crashes otherwise)."""
    e = _edges(f)
    n = int(f.max()) + 1
    _, counts = np.unique(e[:, 0] * n + e[:, 1], return_counts=True)
    if counts.max() > 2:
        raise InputError("<subdivide>", "triangles", "a manifold mesh (no edge shared by more than two triangles)",
                         f"{int((counts > 2).sum())} edges shared by 3 or more")
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    _, dcounts = np.unique(directed[:, 0] * n + directed[:, 1], return_counts=True)
    if dcounts.max() > 1:
        raise InputError("<subdivide>", "triangles", "consistently oriented triangles (neighbours traverse their shared edge in opposite directions)",
                         f"{int((dcounts > 1).sum())} edges traversed twice in the same direction")


def _split_shared_uvs(uv: np.ndarray, f: np.ndarray, ut: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Give every (vertex, UV index) pair its own UV index, so each UV index belongs to one vertex
    (a UV entry reused by corners of different vertices is duplicated; values unchanged)."""
    key = ut.ravel() * (int(f.max()) + 1) + f.ravel()
    unique_keys, inverse = np.unique(key, return_inverse=True)
    source_uv = unique_keys // (int(f.max()) + 1)
    if len(unique_keys) == len(uv) and np.array_equal(source_uv, np.arange(len(uv))):
        return uv, ut
    return uv[source_uv], inverse.reshape(ut.shape).astype(np.int64)


def _loop_matrix(f: np.ndarray, n: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """libigl's Loop matrix (rows: n old vertex points, then edge points) with rows fixed where
    libigl has no rule: unreferenced and non-manifold (bow-tie) vertices are kept in place."""
    import igl

    used = np.unique(f)
    if len(used) == n:
        s, nf = igl.loop_matrix(np.ascontiguousarray(f, dtype=np.int64), int(n))
        s = sp.csr_matrix(s)
        nf = np.asarray(nf, dtype=np.int64)
    else:  # libigl reads out of bounds with unreferenced vertices: call it on the used ones
        compact = np.full(n, -1, dtype=np.int64)
        compact[used] = np.arange(len(used))
        sc, nfc = igl.loop_matrix(np.ascontiguousarray(compact[f]), int(len(used)))
        sc = sp.coo_matrix(sc)
        k = len(used)
        rows = np.where(sc.row < k, used[np.minimum(sc.row, k - 1)], sc.row - k + n)
        s = sp.csr_matrix((sc.data, (rows, used[sc.col])), shape=(n + sc.shape[0] - k, n))
        nfc = np.asarray(nfc, dtype=np.int64)
        nf = np.where(nfc < k, used[np.minimum(nfc, k - 1)], nfc - k + n)
    fixed = np.bincount(f.ravel(), minlength=n) == 0
    e = _edges(f)
    key = e[:, 0] * n + e[:, 1]
    uniq, counts = np.unique(key, return_counts=True)
    boundary = uniq[counts == 1]
    boundary_degree = np.bincount(np.concatenate([boundary // n, boundary % n]), minlength=n)
    fixed |= (boundary_degree != 0) & (boundary_degree != 2)
    if fixed.any():
        s = _replace_rows_with_identity(s, np.flatnonzero(fixed))
    return s, nf


def _replace_rows_with_identity(s: sp.csr_matrix, rows: np.ndarray) -> sp.csr_matrix:
    keep = np.ones(s.shape[0])
    keep[rows] = 0.0
    eye = sp.csr_matrix((np.ones(len(rows)), (rows, rows)), shape=s.shape)
    return (sp.diags(keep) @ s + eye).tocsr()


def _check_child_pattern(f: np.ndarray, nf: np.ndarray) -> None:
    """libigl writes the children of face (a, b, c) as rows 4i..4i+3 = (a, ab, ca), (b, bc, ab),
    (ab, bc, ca), (bc, c, ca); the UV layer relies on it (corner k of child j is the same wedge in
    both meshes). Fail loudly if a libigl version ever changes that."""
    ok = (
        nf.shape == (4 * len(f), 3)
        and np.array_equal(nf[0::4, 0], f[:, 0])
        and np.array_equal(nf[1::4, 0], f[:, 1])
        and np.array_equal(nf[3::4, 1], f[:, 2])
        and np.array_equal(nf[0::4, 1], nf[1::4, 2])
        and np.array_equal(nf[1::4, 1], nf[3::4, 0])
        and np.array_equal(nf[0::4, 2], nf[3::4, 2])
    )
    if not ok:  # pragma: no cover - guards against a change in libigl
        raise RuntimeError("igl.loop_matrix returned children in an unexpected order; facegeo.export.subdivision needs updating")


def _surface_uv_rows(s_geo: sp.csr_matrix, s_uv: sp.csr_matrix, uv_of_vertex: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """Old-vertex UV rows: libigl's UV-mesh row where it equals the geometry's row (mapped to
    vertices), identity elsewhere (seams, junctions). Edge rows are libigl's UV-mesh rows."""
    n_uv = len(uv_of_vertex)
    to_vertex = sp.csr_matrix((np.ones(n_uv), (np.arange(n_uv), uv_of_vertex)), shape=(n_uv, n_vertices))
    mapped = s_uv[:n_uv] @ to_vertex
    diff = abs(mapped - s_geo[uv_of_vertex]).tocsr()
    worst = np.zeros(n_uv)
    if diff.nnz:
        worst = diff.max(axis=1).toarray().ravel()
    return _replace_rows_with_identity(s_uv, np.flatnonzero(worst > 1e-9))


def _linear_uv_rows(s_uv: sp.csr_matrix, n_uv: int) -> sp.csr_matrix:
    """Identity for old vertices; an edge point's UV is the midpoint of its edge (the two entries
    with the largest weight in libigl's row: 3/8 inside, 1/2 on a boundary)."""
    s = s_uv.tocsr()
    rows = np.repeat(np.arange(s.shape[0]), np.diff(s.indptr))
    edge_entries = (rows >= n_uv) & (s.data > 0.3)
    data = np.where(edge_entries, 0.5, 0.0)
    linear = sp.csr_matrix((data, s.indices.copy(), s.indptr.copy()), shape=s.shape)
    linear.eliminate_zeros()
    return _replace_rows_with_identity(linear, np.arange(n_uv))
