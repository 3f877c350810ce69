"""Loop subdivision with face-varying UVs (facegeo.export.subdivision)."""

from __future__ import annotations

import igl
import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from facegeo.asset import Asset
from facegeo.errors import InputError
from facegeo.export.facevarying import FaceVaryingMesh, from_trimesh, to_trimesh, wedges
from facegeo.export.subdivision import subdivide, subdivide_arrays
from test_export_support import grid_mesh, ict_asset, model


def _edges(f):
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    return u, c


def _ict_arrays():
    m = model()
    return m.mean_shape.astype(np.float64), m.triangles, m.uv.astype(np.float64), m.uv_triangles


def _uv_implied_positions(v0, f0, uv0, ut0, uv_query):
    """The point of the coarse surface that each UV addresses (the coarse UV triangle holding it,
    barycentric), and how far inside that triangle it is (min barycentric, < 0 = outside)."""
    tri_uv = uv0[ut0]
    tree = cKDTree(tri_uv.mean(axis=1))
    _, cand = tree.query(uv_query, k=24)
    best = np.zeros(len(uv_query), dtype=np.int64)
    bary = np.zeros((len(uv_query), 3))
    score = np.full(len(uv_query), -np.inf)
    for k in range(cand.shape[1]):
        t = tri_uv[cand[:, k]]
        a, e0, e1 = t[:, 0], t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
        q = uv_query - a
        den = e0[:, 0] * e1[:, 1] - e1[:, 0] * e0[:, 1]
        l1 = (q[:, 0] * e1[:, 1] - e1[:, 0] * q[:, 1]) / den
        l2 = (e0[:, 0] * q[:, 1] - q[:, 0] * e0[:, 1]) / den
        lam = np.stack([1 - l1 - l2, l1, l2], axis=1)
        s = lam.min(axis=1)
        better = s > score
        score[better], best[better], bary[better] = s[better], cand[better, k], lam[better]
    return np.einsum("ij,ijk->ik", bary, v0[f0[best]]), score


def test_geometry_matches_libigl_loop_and_counts():
    v0, f0, uv0, ut0 = _ict_arrays()
    for level in (1, 2):
        v, f, uv, ut = subdivide_arrays(v0, f0, uv0, ut0, level)
        ref_v, ref_f = igl.loop(v0, f0, level)
        np.testing.assert_allclose(v, ref_v, atol=1e-9)
        np.testing.assert_array_equal(f, ref_f)
        assert f.shape == (len(f0) * 4**level, 3) and ut.shape == f.shape
        assert ut.max() < len(uv) and np.isfinite(uv).all()


def test_level_zero_is_identity_and_asset_type_kept():
    a = ict_asset(size=8)
    assert subdivide(a, 0) is a
    s = subdivide(a, 1)
    assert isinstance(s, Asset) and set(s.maps) == set(a.maps) and s.metadata["subdivision_level"] == 1
    assert subdivide(s, 1).metadata["subdivision_level"] == 2


def test_watertight_geometry_and_topology_preserved():
    """Geometry never sees the UV seams: boundary edges only double (no crack along a seam), the
    Euler characteristic is kept, and each geometry vertex has no more UVs than its old one."""
    v0, f0, uv0, ut0 = _ict_arrays()
    _, c0 = _edges(f0)
    v, f, uv, ut = subdivide_arrays(v0, f0, uv0, ut0, 2)
    _, c = _edges(f)
    assert c.max() == 2
    assert (c == 1).sum() == 4 * (c0 == 1).sum()
    euler0 = len(v0) - len(c0) + len(f0)
    assert len(v) - len(c) + len(f) == euler0
    # the UV layer: seams stay seams (UV boundary edges double too), no new seams appear
    _, cu0 = _edges(ut0)
    _, cu = _edges(ut)
    assert (cu == 1).sum() == 4 * (cu0 == 1).sum()
    vw, tw, _ = wedges(f, ut)
    assert np.bincount(vw).max() <= np.bincount(wedges(f0, ut0)[0]).max()


def test_uv_triangles_keep_orientation():
    v0, f0, uv0, ut0 = _ict_arrays()
    for rule in ("surface", "linear"):
        _, _, uv, ut = subdivide_arrays(v0, f0, uv0, ut0, 2, uv_interpolation=rule)
        t = uv[ut]
        d1, d2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
        area2 = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
        assert (area2 > 0).all(), rule


def test_seam_uvs_stay_on_the_coarse_seam_polyline():
    """A seam vertex keeps its UV in each chart and new seam points are edge midpoints, so every
    UV of a fine vertex on a seam (interior of the surface, UV boundary) lies on a coarse UV
    boundary segment: the texture cannot swim across the seam."""
    v0, f0, uv0, ut0 = _ict_arrays()
    v, f, uv, ut = subdivide_arrays(v0, f0, uv0, ut0, 2)
    geo_e, geo_c = _edges(f)
    on_geo_boundary = np.zeros(len(v), bool)
    on_geo_boundary[geo_e[geo_c == 1].ravel()] = True
    uv_e, uv_c = _edges(ut)
    boundary_uv = np.unique(uv_e[uv_c == 1])
    uv_vertex = np.empty(len(uv), np.int64)
    uv_vertex[ut.ravel()] = f.ravel()
    seam_uv = boundary_uv[~on_geo_boundary[uv_vertex[boundary_uv]]]
    assert len(seam_uv) > 1000
    ce, cc = _edges(ut0)
    seg = uv0[ce[cc == 1]]  # (S, 2, 2)
    p = uv[seam_uv]
    _, near = cKDTree(seg.mean(axis=1)).query(p, k=8)  # candidate segments around each point
    a, d = seg[near, 0], seg[near, 1] - seg[near, 0]  # (P, 8, 2)
    q = p[:, None, :] - a
    t = np.clip(np.sum(q * d, axis=2) / np.sum(d * d, axis=2), 0, 1)
    best = np.linalg.norm(q - t[..., None] * d, axis=2).min(axis=1)
    assert best.max() < 1e-9


def test_uvs_follow_the_surface_no_swimming():
    """The coarse-surface point each fine UV addresses is close to the fine vertex (its texel
    belongs to it): on average within 0.1 mm at every level, about the Loop smoothing's own
    deviation from the coarse surface, and 2.5x closer than with midpoint (linear) UVs."""
    v0, f0, uv0, ut0 = _ict_arrays()
    errors = {}
    for rule in ("surface", "linear"):
        v, f, uv, ut = subdivide_arrays(v0, f0, uv0, ut0, 2, uv_interpolation=rule)
        vw, tw, _ = wedges(f, ut)
        implied, score = _uv_implied_positions(v0, f0, uv0, ut0, uv[tw])
        err = np.linalg.norm(implied - v[vw], axis=1)
        errors[rule] = err
        assert err.max() < 3.0, rule  # mm: no point addresses another part of the head
        if rule == "linear":
            assert score.min() > -1e-9  # midpoints never leave the coarse charts
    assert errors["surface"].mean() < 0.1
    assert errors["surface"].mean() < 0.5 * errors["linear"].mean()


def test_flat_grid_uv_follows_positions_exactly():
    """On a flat mesh whose UV is an affine function of position, Loop smoothing moves vertices
    only within the plane and the UVs must follow exactly (interior), boundary included (the
    mesh boundary is also the UV boundary: both use the B-spline rule)."""
    v0, f0, uv0, ut0 = grid_mesh(6, 12.0)
    v, f, uv, ut = subdivide_arrays(v0, f0, uv0, ut0, 3)
    uv_vertex = np.empty(len(uv), np.int64)
    uv_vertex[ut.ravel()] = f.ravel()
    np.testing.assert_allclose(uv, v[uv_vertex, :2] / 12.0, atol=1e-12)


def test_trimesh_through_from_and_to_trimesh_welded():
    a = ict_asset(size=8)
    tm = to_trimesh(a)
    assert len(tm.vertices) == len(wedges(a.triangles, a.uv_triangles)[0])
    fv = from_trimesh(tm)
    assert len(fv.vertices) == len(a.vertices)  # seam duplicates welded again
    with pytest.raises(InputError, match="from_trimesh"):  # export takes facegeo's types only
        subdivide(tm, 1)
    out = to_trimesh(subdivide(fv, 1))
    assert isinstance(out, trimesh.Trimesh) and out.visual.uv is not None
    assert len(out.faces) == 4 * len(a.triangles)
    direct = subdivide(a, 1)
    gap, _ = cKDTree(direct.vertices).query(out.vertices)
    assert gap.max() < 1e-3  # the same surface (float32 storage of the Asset aside)
    # the welded result is as watertight as the Asset's: boundary edges equal
    _, c1 = _edges(from_trimesh(out).triangles)
    _, c2 = _edges(direct.triangles)
    assert (c1 == 1).sum() == (c2 == 1).sum()


def test_mesh_without_uvs():
    v0, f0, _, _ = grid_mesh(3)
    v, f, uv, ut = subdivide_arrays(v0, f0, None, None, 2)
    assert uv is None and ut is None and len(f) == 16 * len(f0)


def test_degenerate_inputs_are_handled():
    v0, f0, uv0, ut0 = grid_mesh(3)
    # a face repeating a vertex (no area; libigl would crash) is dropped
    f1 = np.vstack([f0, [[0, 0, 1]]])
    u1 = np.vstack([ut0, [[0, 0, 1]]])
    v, f, uv, ut = subdivide_arrays(v0, f1, uv0, u1, 1)
    assert len(f) == 4 * len(f0)
    # a zero-area (collinear) triangle with distinct vertices is subdivided, stays finite
    v2 = np.vstack([v0, [[20.0, 0, 0], [30.0, 0, 0], [40.0, 0, 0]]])
    f2 = np.vstack([f0, [[16, 17, 18]]])
    uv2 = np.vstack([uv0, [[0.9, 0.1], [0.95, 0.1], [1.0, 0.1]]])
    u2 = np.vstack([ut0, [[16, 17, 18]]])
    v, f, uv, ut = subdivide_arrays(v2, f2, uv2, u2, 2)
    assert np.isfinite(v).all() and np.isfinite(uv).all()
    # an unreferenced vertex stays where it is (libigl would scale it by 5/8)
    v3 = np.vstack([v0, [[50.0, 50.0, 50.0]]])
    v, *_ = subdivide_arrays(v3, f0, uv0, ut0, 1)
    np.testing.assert_allclose(v[len(v0)], [50.0, 50.0, 50.0])
    # a UV index shared by corners of different vertices is split, values kept
    u4 = ut0.copy()
    u4[0, 0] = u4[5, 1]
    v, f, uv, ut = subdivide_arrays(v0, f0, uv0, u4, 1)
    uv_vertex = {}
    for fv_, tv_ in zip(f.ravel(), ut.ravel()):
        assert uv_vertex.setdefault(tv_, fv_) == fv_


def test_bow_tie_vertex_is_kept():
    v0 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], float)
    f0 = np.array([[0, 1, 2], [0, 3, 4]])
    uv0 = v0[:, :2] * 0.4 + 0.5
    v, f, uv, ut = subdivide_arrays(v0, f0, uv0, f0.copy(), 1)
    np.testing.assert_allclose(v[0], [0, 0, 0])
    assert np.isfinite(uv).all()


def test_non_manifold_edge_and_bad_arguments_raise():
    v0 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
    f0 = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    with pytest.raises(InputError, match="manifold"):
        subdivide_arrays(v0, f0, None, None, 1)
    v1, f1, uv1, ut1 = grid_mesh(2)
    flipped = f1.copy()
    flipped[0] = flipped[0, ::-1]  # inconsistent orientation (libigl would crash)
    with pytest.raises(InputError, match="oriented"):
        subdivide_arrays(v1, flipped, uv1, ut1, 1)
    with pytest.raises(InputError, match="level"):
        subdivide_arrays(v1, f1, uv1, ut1, -1)
    with pytest.raises(InputError, match="level"):
        subdivide_arrays(v1, f1, uv1, ut1, 1.5)
    with pytest.raises(InputError, match="uv_interpolation"):
        subdivide_arrays(v1, f1, uv1, ut1, 1, uv_interpolation="smooth")
    with pytest.raises(InputError, match="triangles"):
        subdivide_arrays(v1, f1 + 100, uv1, ut1, 1)
    with pytest.raises(InputError, match="mesh"):
        subdivide("not a mesh", 1)


def test_face_varying_mesh_roundtrip():
    v0, f0, uv0, ut0 = grid_mesh(2)
    out = subdivide(FaceVaryingMesh(v0, f0, uv0, ut0), 1)
    assert isinstance(out, FaceVaryingMesh) and len(out.triangles) == 4 * len(f0)
