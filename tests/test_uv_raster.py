"""facegeo.uv.rasterize_uv: coverage, exact tie rule, barycentrics, seam padding, cache, errors."""

import numpy as np
import pytest

from facegeo.errors import InputError
from facegeo.uv import UVRaster, clear_raster_cache, default_padding, rasterize_uv
from facegeo.uv.texels import texel_centres_uv


def _texel_uv(raster):
    u, v = texel_centres_uv(raster.size)
    return np.stack([u, v], axis=-1).reshape(-1, 2)[raster.texels]


def test_unit_square_is_covered_once_and_barycentrics_reproduce_texel_centres():
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    for S in (1, 2, 7, 64):
        r = rasterize_uv(uv, tris, size=S, padding=0, cache=False)
        assert r.inside.all() and r.mask.all() and r.texels.size == S * S
        back = np.einsum("nk,nkc->nc", r.texel_barycentric.astype(np.float64), uv[tris[r.texel_triangle]])
        np.testing.assert_allclose(back, _texel_uv(r), atol=1e-6)
        assert (r.texel_barycentric >= 0).all()
        np.testing.assert_allclose(r.texel_barycentric.sum(1), 1.0, atol=1e-6)


def test_edges_through_texel_centres_give_each_texel_to_one_triangle():
    # a fan and a grid whose edges and vertices lie exactly on texel centres of an 8x8 map
    S = 8
    c = (np.arange(S) + 0.5) / S
    gu, gv = np.meshgrid(c, c)
    uv = np.stack([gu.ravel(), gv.ravel()], 1)
    tris = []
    for j in range(S - 1):
        for i in range(S - 1):
            a = j * S + i
            tris += [[a, a + 1, a + S + 1], [a, a + S + 1, a + S]] if (i + j) % 2 else [[a, a + 1, a + S], [a + 1, a + S + 1, a + S]]
    tris = np.array(tris)
    r = rasterize_uv(uv, tris, size=S, padding=0, cache=False)
    # rasterising triangle by triangle: no texel centre is claimed twice, interior centres (on
    # shared edges and vertices) exactly once; on the outer border only the owned edges count
    counts = np.zeros(S * S, int)
    for t in range(len(tris)):
        one = rasterize_uv(uv, tris[t:t + 1], size=S, padding=0, cache=False)
        counts[one.texels] += 1
    counts = counts.reshape(S, S)
    assert counts.max() == 1
    assert (counts[1:-1, 1:-1] == 1).all()
    np.testing.assert_array_equal(counts == 1, r.inside)


def test_mirrored_and_degenerate_uv_triangles(model):
    uv = np.array([[0.1, 0.1], [0.9, 0.1], [0.5, 0.9], [0.3, 0.3], [0.6, 0.6]])
    # clockwise (mirrored) triangle, a collinear one and a single-point one
    tris = np.array([[0, 2, 1], [0, 3, 4], [3, 3, 3]])
    r = rasterize_uv(uv, tris, size=32, padding=2, cache=False)
    assert set(np.unique(r.texel_triangle[r.texel_inside])) == {0}
    assert np.isfinite(r.texel_barycentric).all()
    back = np.einsum("nk,nkc->nc", r.texel_barycentric[r.texel_inside].astype(np.float64), uv[tris[r.texel_triangle[r.texel_inside]]])
    np.testing.assert_allclose(back, _texel_uv(r)[r.texel_inside], atol=1e-6)
    only_degenerate = rasterize_uv(uv, tris[1:], size=32, padding=4, cache=False)
    assert only_degenerate.texels.size == 0 and (only_degenerate.triangle == -1).all()


def test_ict_layout_coverage_matches_uv_area(model):
    r = rasterize_uv(model, size=512)
    uv = model.uv.astype(np.float64)[model.uv_triangles]
    area = 0.5 * np.abs((uv[:, 1, 0] - uv[:, 0, 0]) * (uv[:, 2, 1] - uv[:, 0, 1])
                        - (uv[:, 1, 1] - uv[:, 0, 1]) * (uv[:, 2, 0] - uv[:, 0, 0])).sum()
    assert abs(r.inside.mean() - area) < 0.002
    inside = r.texel_inside
    back = np.einsum("nk,nkc->nc", r.texel_barycentric[inside].astype(np.float64), uv[r.texel_triangle[inside]])
    np.testing.assert_allclose(back, _texel_uv(r)[inside], atol=2e-6)
    assert r.triangle.dtype == np.int32 and r.triangle.shape == (512, 512)
    assert (r.triangle[~r.mask] == -1).all() and (r.barycentric[~r.mask] == 0).all()


def test_padding_band_and_closest_points(model):
    n = 6
    r = rasterize_uv(model, size=256, padding=n, cache=False)
    import cv2

    grown = cv2.dilate(r.inside.astype(np.uint8), np.ones((2 * n + 1, 2 * n + 1), np.uint8)) > 0
    np.testing.assert_array_equal(r.mask, grown)
    pad = ~r.texel_inside
    b = r.texel_barycentric[pad]
    assert (b >= 0).all() and np.allclose(b.sum(1), 1.0, atol=1e-6)
    # a padded texel's point lies on its triangle's border, near the texel (≤ n·√2 texels)
    uv = model.uv.astype(np.float64)[model.uv_triangles]
    p = np.einsum("nk,nkc->nc", b.astype(np.float64), uv[r.texel_triangle[pad]])
    d = np.linalg.norm(p - _texel_uv(r)[pad], axis=1) * 256
    assert d.max() <= n * np.sqrt(2) + 1.5
    assert (b.min(axis=1) < 1e-6).all()


@pytest.mark.parametrize("levels", [1, 2])
def test_bilinear_and_mip_lookups_never_touch_background(model, levels):
    S = 512
    n = 2 ** (levels + 1)
    r = rasterize_uv(model, size=S, padding=n, cache=False)
    covered = r.mask.astype(np.float64)
    for k in range(levels + 1):
        f = 2 ** k
        coarse = covered.reshape(S // f, f, S // f, f).mean(axis=(1, 3))
        # bilinear lookup at every inside texel centre, at level k
        rows, cols = np.nonzero(r.inside)
        x = (cols + 0.5) / f - 0.5
        y = (rows + 0.5) / f - 0.5
        x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
        for dx in (0, 1):
            for dy in (0, 1):
                xi, yi = np.clip(x0 + dx, 0, S // f - 1), np.clip(y0 + dy, 0, S // f - 1)
                assert coarse[yi, xi].min() == 1.0, f"level {k} touches background"


def test_full_fill_padding(model):
    r = rasterize_uv(model, size=64, padding=64, cache=False)
    assert r.mask.all() and r.padding == 64


def test_cache_returns_the_same_raster(model):
    clear_raster_cache()
    a = rasterize_uv(model, size=128)
    b = rasterize_uv(model.uv, model.uv_triangles, size=128)
    assert a is b and a.padding == default_padding(128) == 2
    assert rasterize_uv(model, size=128, padding=0) is not a
    assert not a.texels.flags.writeable and not a.triangle.flags.writeable
    clear_raster_cache()
    assert rasterize_uv(model, size=128) is not a
    assert isinstance(a, UVRaster) and "size=128" in repr(a)


def test_scatter_gather_interpolate(model):
    r = rasterize_uv(model, size=64)
    values = np.arange(r.texels.size, dtype=np.float32)
    dense = r.scatter(values, fill=-1)
    assert dense.shape == (64, 64) and (dense[~r.mask] == -1).all()
    np.testing.assert_array_equal(r.gather(dense), values)
    ones = r.interpolate(np.ones((model.triangles.shape[0], 3, 2)))
    np.testing.assert_allclose(ones, 1.0, atol=1e-6)


@pytest.mark.parametrize("args", [
    (np.zeros((3, 3)), np.array([[0, 1, 2]])),
    (np.array([[0, 0], [1, 0], [np.nan, 1]]), np.array([[0, 1, 2]])),
    (np.array([[0, 0], [1, 0], [0, 1]]), np.array([[0, 1, 3]])),
    (np.array([[0, 0], [1, 0], [0, 1]]), np.array([[0.0, 1, 2]])),
])
def test_bad_layouts_raise_input_error(args):
    with pytest.raises(InputError):
        rasterize_uv(*args, size=8)


def test_bad_size_and_padding(model):
    with pytest.raises(InputError):
        rasterize_uv(model, size=0)
    with pytest.raises(InputError):
        rasterize_uv(model, size=8, padding=-1)
    with pytest.raises(InputError):
        rasterize_uv(object(), size=8)
