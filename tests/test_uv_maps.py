"""facegeo.uv.geometry_maps: position, normal, MikkTSpace tangent and sign maps."""

import numpy as np
import pytest

from facegeo.errors import InputError
from facegeo.uv import geometry_maps, mesh_tangents, rasterize_uv, vertex_normals


def test_flat_quad_maps_are_exact():
    class Quad:
        triangles = np.array([[0, 1, 2], [0, 2, 3]])
        uv_triangles = triangles
        uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)

    V = np.array([[0, 0, 0], [100, 0, 0], [100, 50, 0], [0, 50, 0]], np.float32)
    r = rasterize_uv(Quad.uv, Quad.uv_triangles, size=16, padding=0)
    g = geometry_maps(V, Quad, r)
    c = (np.arange(16) + 0.5) / 16
    np.testing.assert_allclose(g.position[..., 0], np.broadcast_to(100 * c[None, :], (16, 16)), atol=1e-4)
    np.testing.assert_allclose(g.position[..., 1], np.broadcast_to(50 * (1 - c)[:, None], (16, 16)), atol=1e-4)
    np.testing.assert_allclose(g.normal, np.broadcast_to([0, 0, 1], (16, 16, 3)), atol=1e-6)
    np.testing.assert_allclose(g.tangent, np.broadcast_to([1, 0, 0], (16, 16, 3)), atol=1e-6)
    np.testing.assert_array_equal(g.bitangent_sign, 1)
    np.testing.assert_allclose(g.bitangent(), np.broadcast_to([0, 1, 0], (16, 16, 3)), atol=1e-6)


def test_ict_maps(model):
    r = rasterize_uv(model, size=256)
    g = geometry_maps(model.mean_shape, model, r)
    assert g.position.shape == g.normal.shape == g.tangent.shape == (256, 256, 3)
    assert g.bitangent_sign.shape == (256, 256)
    for a in (g.position, g.normal, g.tangent, g.bitangent_sign):
        assert a.dtype == np.float32 and np.isfinite(a).all()
        assert (a[~g.mask] == 0).all()
    m = g.mask
    np.testing.assert_allclose(np.linalg.norm(g.normal[m], axis=1), 1, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(g.tangent[m], axis=1), 1, atol=1e-5)
    assert set(np.unique(g.bitangent_sign[m])) == {1.0}
    # interpolated frames stay close to orthogonal
    nt = np.abs((g.normal[m] * g.tangent[m]).sum(1))
    assert np.quantile(nt, 0.999) < 0.05 and nt.max() < 0.5
    # positions are the barycentric interpolation of the covering triangle
    tri = r.texel_triangle
    corners = model.mean_shape[model.triangles[tri]]
    expect = np.einsum("nk,nkc->nc", r.texel_barycentric, corners)
    np.testing.assert_allclose(r.gather(g.position), expect, atol=1e-3)
    # tangents are the interpolated MikkTSpace corner tangents
    corner_t = mesh_tangents(model.mean_shape, model.triangles, model.uv, model.uv_triangles)
    t = np.einsum("nk,nkc->nc", r.texel_barycentric, corner_t[tri, :, :3])
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    np.testing.assert_allclose(r.gather(g.tangent), t, atol=1e-5)
    # normals agree with the face normals
    c = model.mean_shape[model.triangles].astype(np.float64)
    fn = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    assert ((fn[tri] * r.gather(g.normal)).sum(1) > 0).mean() > 0.995
    assert g.texel["position"].shape == (r.texels.size, 3)


def test_maps_without_tangents_and_custom_normals(model):
    r = rasterize_uv(model, size=64)
    g = geometry_maps(model.mean_shape, model, r, tangents=False)
    assert g.tangent is None and g.bitangent_sign is None
    with pytest.raises(ValueError):
        g.bitangent()
    flipped = -vertex_normals(model.mean_shape, model.triangles)
    g2 = geometry_maps(model.mean_shape, model, r, normals=flipped)
    np.testing.assert_allclose(g2.normal, -g.normal, atol=1e-6)


def test_degenerate_mesh_triangles_give_finite_maps(model):
    V = model.mean_shape.copy()
    rng = np.random.default_rng(0)
    sel = rng.choice(model.triangles.shape[0], 500, replace=False)
    V[model.triangles[sel, 1]] = V[model.triangles[sel, 0]]
    V[model.triangles[sel[:50], 2]] = V[model.triangles[sel[:50], 0]]  # collapsed to points
    g = geometry_maps(V, model, size=128)
    for a in (g.position, g.normal, g.tangent, g.bitangent_sign):
        assert np.isfinite(a).all()


def test_bad_vertices(model):
    with pytest.raises(InputError):
        geometry_maps(np.zeros((10, 3)), model, size=32)
    bad = model.mean_shape.copy()
    bad[0, 0] = np.inf
    with pytest.raises(InputError):
        geometry_maps(bad, model, size=32)
    small = rasterize_uv(np.array([[0, 0], [1, 0], [0, 1]]), np.array([[0, 1, 2]]), size=8)
    with pytest.raises(InputError):
        geometry_maps(model.mean_shape, model, small)
