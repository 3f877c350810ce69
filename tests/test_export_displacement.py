"""Bilinear sampling and displacement baking (facegeo.export.displacement)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from facegeo.asset import Asset
from facegeo.errors import InputError
from facegeo.export.displacement import bake_displacement, displace, vertex_values
from facegeo.uv.texels import sample_uv
from facegeo.normals import vertex_normals
from facegeo.export.facevarying import FaceVaryingMesh, from_trimesh, wedges
from test_export_support import grid_mesh, ict_asset, synthetic_maps


def test_sample_uv_texel_centres_orientation_and_bilinear():
    img = np.arange(12, dtype=np.float64).reshape(3, 4)  # row 0 = top (v near 1)
    h, w = img.shape
    centres = np.array([[(j + 0.5) / w, 1 - (i + 0.5) / h] for i in range(h) for j in range(w)])
    np.testing.assert_allclose(sample_uv(img, centres), img.ravel())
    mid = np.array([[1.0 / w, 1 - 1.0 / h]])  # between texels (0,0),(0,1),(1,0),(1,1)
    np.testing.assert_allclose(sample_uv(img, mid), [np.mean([0, 1, 4, 5])])
    np.testing.assert_allclose(sample_uv(img, np.array([[-1.0, 2.0], [2.0, -1.0]])), [0.0, 11.0])  # clamped
    rgb = np.dstack([img, 2 * img, 3 * img])
    np.testing.assert_allclose(sample_uv(rgb, centres[:3]), np.stack([img.ravel()[:3], 2 * img.ravel()[:3], 3 * img.ravel()[:3]], 1))
    one = np.array([[7.0]])
    np.testing.assert_allclose(sample_uv(one, centres), 7.0)


def test_constant_displacement_moves_along_normals():
    a = ict_asset(maps={})
    moved = bake_displacement(a, np.full((8, 8), 0.5, np.float32))
    n = vertex_normals(a.vertices, a.triangles)
    np.testing.assert_allclose(moved.vertices - a.vertices, 0.5 * n, atol=2e-5)
    scaled = bake_displacement(a, 0.25, scale_mm=2.0)
    np.testing.assert_allclose(scaled.vertices, moved.vertices, atol=1e-5)


def test_seam_vertices_get_one_value():
    """A map that differs between the two charts of a seam moves a seam vertex by the mean of its
    samples: one value, so the surface stays closed."""
    a = ict_asset(maps={})
    img = np.tile(np.linspace(-1, 1, 64, dtype=np.float32), (64, 1))  # depends on u
    values = vertex_values(a, img)
    vw, tw, _ = wedges(a.triangles, a.uv_triangles)
    per_wedge = sample_uv(img, a.uv[tw])
    seam = np.flatnonzero(np.bincount(vw) > 1)
    assert len(seam) > 100
    for vtx in seam[:50]:
        np.testing.assert_allclose(values[vtx], per_wedge[vw == vtx].mean(), atol=1e-6)
    moved = bake_displacement(a, img)
    assert len(moved.vertices) == len(a.vertices)
    np.testing.assert_array_equal(moved.triangles, a.triangles)


def test_displace_asset_drops_its_displacement_and_records_it():
    a = ict_asset(size=32)
    d = displace(a, level=1)
    assert isinstance(d, Asset) and "displacement" not in d.maps
    assert d.metadata["displacement_baked"] == {"scale_mm": 1.0, "level": 1}
    assert len(d.triangles) == 4 * len(a.triangles)
    explicit = displace(a, a.maps["displacement"], 1)
    np.testing.assert_allclose(explicit.vertices, d.vertices, atol=1e-5)
    other = displace(a, np.zeros((4, 4), np.float32), 1)  # someone else's map: the asset keeps its own
    assert "displacement" in other.maps
    # the displaced surface differs from the plain subdivided one by the map's magnitude
    from facegeo.export.subdivision import subdivide

    gap = np.linalg.norm(d.vertices - subdivide(a, 1).vertices, axis=1)
    assert 0.05 < gap.max() <= 0.4 + 1e-4


def test_displace_via_trimesh_round_trip_keeps_uvs():
    a = ict_asset(maps={})
    from facegeo.export.facevarying import to_trimesh

    tm = to_trimesh(a)
    out = to_trimesh(displace(from_trimesh(tm), synthetic_maps(32)["displacement"], level=1))
    assert isinstance(out, trimesh.Trimesh)
    assert out.visual.uv is not None and len(out.visual.uv) == len(out.vertices)
    fv = from_trimesh(out)
    assert len(fv.triangles) == 4 * len(a.triangles)
    assert np.isfinite(out.vertices).all() and np.isfinite(out.vertex_normals).all()


def test_bake_with_degenerate_triangles_is_finite():
    v, f, uv, ut = grid_mesh(3)
    v = np.vstack([v, [[100, 0, 0.0], [101, 0, 0.0], [102, 0, 0.0]]])
    f = np.vstack([f, [[16, 17, 18]]])
    uv = np.vstack([uv, [[0.1, 0.1], [0.1, 0.1], [0.1, 0.1]]])  # zero UV area too
    ut = np.vstack([ut, [[16, 17, 18]]])
    out = displace(FaceVaryingMesh(v, f, uv, ut), np.ones((8, 8), np.float32), level=2)
    assert np.isfinite(out.vertices).all()


def test_bad_maps_raise():
    a = ict_asset(maps={})
    with pytest.raises(InputError, match="displacement_map"):
        bake_displacement(a)
    with pytest.raises(InputError, match="displacement_map"):
        displace(a, level=1)
    bad = np.ones((4, 4), np.float32)
    bad[0, 0] = np.nan
    with pytest.raises(InputError, match="finite"):
        bake_displacement(a, bad)
    with pytest.raises(InputError, match=r"\(H, W\)"):
        bake_displacement(a, np.ones((4, 4, 3)))
    with pytest.raises(InputError, match="scale_mm"):
        bake_displacement(a, bad * 0 + 1, scale_mm=float("inf"))
    v, f, _, _ = grid_mesh(2)
    with pytest.raises(InputError, match="uv"):
        bake_displacement(FaceVaryingMesh(v, f), np.ones((2, 2)))
