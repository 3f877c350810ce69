"""The texture context of a fit: mirror map, regions, geometry in UV."""

import numpy as np
import pytest

from facegeo import Camera, fit_landmarks, load_model, project
from facegeo.texturing.context import build_context, mirror_vertices
from facegeo.skin_mask import REGION_NAMES, vertex_regions
from facegeo.uv.raster import rasterize_uv


@pytest.fixture(scope="module")
def context():
    model = load_model()
    camera = Camera.for_image(512, 512)
    lm = project(model.mean_shape[model.landmark_indices].astype(np.float64), np.eye(3), np.array([0, 0, -600.0]), camera)
    fit = fit_landmarks(model, lm, camera)
    return model, build_context(model, fit, rasterize_uv(model, size=256))


def test_mirror_vertices_of_the_symmetric_model():
    model = load_model()
    partner = mirror_vertices(model)
    ok = partner >= 0
    assert ok[model.face_mask].mean() > 0.99
    np.testing.assert_array_equal(partner[partner[ok]], np.flatnonzero(ok))
    reflected = model.mean_shape[partner[ok]] * [-1, 1, 1]
    assert np.abs(reflected - model.mean_shape[ok]).max() < 1.0


def test_mirror_map_is_an_involution_on_the_face(context):
    _, ctx = context
    mirror = ctx.mirror
    ok = mirror[..., 0] >= 0
    assert ok[ctx.coverage].mean() > 0.95
    rows, cols = np.nonzero(ok)
    back = mirror[mirror[rows, cols, 0], mirror[rows, cols, 1]]
    valid = back[:, 0] >= 0
    err = np.abs(back[valid] - np.stack([rows, cols], 1)[valid]).max(1)
    assert np.percentile(err, 99) <= 1


def test_regions_are_present_symmetric_and_bounded(context):
    model, ctx = context
    per_vertex = vertex_regions(model)
    partner = mirror_vertices(model)
    ok = partner >= 0
    for name in REGION_NAMES:
        mask = per_vertex[name]
        assert 0.0 <= mask.min() and mask.max() <= 1.0
        assert (mask > 0.5).sum() > 50, name
        np.testing.assert_allclose(mask[ok], mask[partner[ok]], atol=0.01)  # partners lie within 1 mm
        assert (ctx.regions[name] > 0.5).sum() > 100, name


def test_geometry_maps_in_context(context):
    _, ctx = context
    n = ctx.normal_camera[ctx.coverage]
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-4)
    assert 0.2 < np.median(ctx.texel_size_mm[ctx.coverage]) < 5.0  # mm per texel at S = 256
    assert ctx.mean_texture.shape == (256, 256, 3) and ctx.gamma.shape == (3, 9)


def test_surface_operators_round_trip_and_seamless_fill(context):
    """Vertex values reach the texels exactly (barycentric rows sum to 1) and come back; the
    default backend's fill, built on them, gives both sides of every UV seam the same colour."""
    from facegeo.texturing.default import DefaultBackend

    model, ctx = context
    surf, S = ctx.surface, ctx.size
    x = model.mean_shape[:, 0].astype(np.float64)  # a linear function of the position
    np.testing.assert_allclose(surf.to_texels(np.ones(model.n_vertices), S)[ctx.coverage], 1.0, atol=1e-5)
    texels = surf.to_texels(x, S)
    back, weight = surf.to_vertices(texels, ctx.coverage.astype(np.float32))
    used = weight > 0.5
    err = np.abs(back[used] - x[used])  # mm: a weighted mean over the vertex's one-ring of texels
    assert used.mean() > 0.85 and np.median(err) < 0.5 and err.max() < 8.0
    assert np.allclose(np.asarray(surf.laplacian.sum(axis=1)).ravel(), 0)
    # the fill of a texture seen only on the left half of the layout: seam pairs agree
    rng = np.random.default_rng(0)
    t_inc = np.clip(0.6 + 0.05 * rng.normal(size=(S, S, 3)), 0, 1).astype(np.float32)
    vis = (ctx.coverage & (np.arange(S)[None, :] < S // 2)).astype(np.float32)
    albedo = DefaultBackend().homogenise(DefaultBackend().inpaint(t_inc, vis, ctx), ctx)
    tri, uvt = np.asarray(model.triangles).ravel(), np.asarray(model.uv_triangles).ravel()
    pairs = np.unique(np.stack([tri, uvt], 1), axis=0)
    same = np.flatnonzero(pairs[1:, 0] == pairs[:-1, 0])
    uv_a, uv_b = model.uv[pairs[same, 1]], model.uv[pairs[same + 1, 1]]
    px = lambda uv: (np.clip(((1 - uv[:, 1]) * S).astype(int), 0, S - 1), np.clip((uv[:, 0] * S).astype(int), 0, S - 1))  # noqa: E731
    a, b = px(uv_a), px(uv_b)
    inside = ctx.coverage[a] & ctx.coverage[b]  # a nearest texel outside the layout reads the padding, not the seam
    assert inside.sum() > 100
    assert np.percentile(np.abs(albedo[a] - albedo[b]).max(axis=1)[inside], 90) < 0.03  # (0.0: the same value)
