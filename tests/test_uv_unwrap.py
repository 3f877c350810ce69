"""facegeo.uv.unwrap and render: the round trip, the ray-casting oracle, extreme poses, degenerate
geometry, faces partly outside the image, the external occlusion mask and bad input."""

import numpy as np
import pytest
from test_uv_support import oracle_visible, painted_texture, posed_fit, psnr

import facegeo
from facegeo.errors import InputError
from facegeo.uv import rasterize_uv, render, unwrap, unwrap_details


@pytest.fixture(scope="module")
def raster1024(model):
    return rasterize_uv(model, size=1024)


@pytest.mark.parametrize("yaw", [0.0, 35.0])
def test_round_trip_psnr_at_1024(model, raster1024, yaw):
    """The bar: paint a texture on the posed mesh, render it, unwrap it: ≥ 35 dB on M_vis > 0.5."""
    texture = painted_texture(model, raster1024)
    fit = posed_fit(model, yaw=yaw, pitch=10.0, size=1024)
    image = render(fit.vertices, model, fit.camera, texture=texture).image
    t_inc, m_vis = unwrap(image, fit, model, raster=raster1024)
    sel = m_vis > 0.5
    assert sel.sum() > 200_000
    assert psnr(t_inc, texture, sel) >= 35.0
    assert (t_inc[m_vis == 0] == 0).all()


def test_round_trip_at_photo_resolution(model):
    """A 512-pixel photo carries less detail than a 1024 map; at S = 512 it still comes back."""
    r = rasterize_uv(model, size=512)
    texture = painted_texture(model, r)
    fit = posed_fit(model, yaw=-20.0, size=512)
    image = render(fit.vertices, model, fit.camera, texture=texture).image
    t_inc, m_vis = unwrap((image * 255).round().astype(np.uint8), fit, model, raster=r)
    assert psnr(t_inc, texture, m_vis > 0.5) >= 33.0


@pytest.mark.parametrize("yaw", [0.0, 45.0, 80.0])
def test_visibility_agrees_with_ray_casting(model, yaw):
    r = rasterize_uv(model, size=512)
    fit = posed_fit(model, yaw=yaw, size=512)
    image = np.full((512, 512, 3), 0.5, np.float32)
    u = unwrap_details(image, fit, model, raster=r)
    oracle, ours = oracle_visible(model, fit, r, u)
    assert (oracle == ours).mean() >= 0.99
    assert oracle.sum() > 20_000
    # M_vis > 0 only where the oracle sees the texel
    vis = u.visibility[r.inside] > 0
    assert (vis & ~oracle).sum() <= 0.005 * vis.sum()


@pytest.mark.slow
@pytest.mark.parametrize("yaw", [0.0, 45.0, 80.0])
def test_visibility_agrees_with_ray_casting_at_1024(model, raster1024, yaw):
    fit = posed_fit(model, yaw=yaw, pitch=5.0, size=1024)
    u = unwrap_details(np.zeros((1024, 1024, 3), np.uint8), fit, model, raster=raster1024)
    oracle, ours = oracle_visible(model, fit, raster1024, u)
    assert (oracle == ours).mean() >= 0.995


@pytest.mark.parametrize("yaw,pitch", [(90, 0), (-90, 0), (0, 60), (0, -60), (90, 60), (180, 0)])
def test_extreme_poses(model, yaw, pitch):
    r = rasterize_uv(model, size=256)
    fit = posed_fit(model, yaw=yaw, pitch=pitch, size=256)
    image = np.random.default_rng(0).random((256, 256, 3)).astype(np.float32)
    u = unwrap_details(image, fit, model, raster=r)
    for a in (u.texture, u.visibility, u.coverage, u.facing, u.cos_view, u.pixel):
        assert np.isfinite(a).all()
    assert 0 <= u.visibility.min() and u.visibility.max() <= 1
    oracle, ours = oracle_visible(model, fit, r, u)
    assert (oracle == ours).mean() >= 0.99
    assert ((u.visibility[r.inside] > 0) & ~oracle).sum() <= max(20, 0.01 * oracle.sum())


def test_face_partly_outside_the_image(model):
    r = rasterize_uv(model, size=256)
    fit = posed_fit(model, yaw=20, size=256, shift=(230.0, 90.0))
    texture = painted_texture(model, r)
    image = render(fit.vertices, model, fit.camera, texture=texture).image
    u = unwrap_details(image, fit, model, raster=r)
    px = u.pixel[r.mask]
    outside = (px[:, 0] < 0) | (px[:, 0] > 256) | (px[:, 1] < 0) | (px[:, 1] > 256)
    assert outside.mean() > 0.2  # a good part of the head is off-screen
    assert (u.visibility[r.mask][outside] == 0).all()
    assert (~u.visible[r.mask][outside]).all()
    assert (u.visibility > 0.5).sum() > 1000 and np.isfinite(u.texture).all()
    oracle, ours = oracle_visible(model, fit, r, u)
    assert (oracle == ours).mean() >= 0.99


def test_camera_inside_or_behind_gives_nothing(model):
    fit = posed_fit(model, size=128, distance=-400.0)  # the head behind the camera
    t_inc, m_vis = unwrap(np.zeros((128, 128, 3), np.uint8), fit, model, size=128)
    assert (m_vis == 0).all() and (t_inc == 0).all()


def test_degenerate_mesh_and_uv_triangles(model):
    rng = np.random.default_rng(1)
    V = model.mean_shape.copy()
    sel = rng.choice(model.triangles.shape[0], 400, replace=False)
    V[model.triangles[sel, 1]] = V[model.triangles[sel, 0]]
    V[model.triangles[sel[:40], 2]] = V[model.triangles[sel[:40], 0]]

    class Degenerate:
        triangles = model.triangles
        uv = model.uv
        uv_triangles = model.uv_triangles.copy()

    Degenerate.uv_triangles[sel[::2], 2] = Degenerate.uv_triangles[sel[::2], 0]
    r = rasterize_uv(Degenerate, size=256)
    fit = posed_fit(model, yaw=30, size=256, vertices=V)
    image = np.random.default_rng(2).random((256, 256, 3)).astype(np.float32)
    u = unwrap_details(image, fit, Degenerate, raster=r)
    assert np.isfinite(u.texture).all() and np.isfinite(u.visibility).all()
    c = fit.vertices[model.triangles].astype(np.float64)
    zero = np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1) == 0
    on_zero = zero[np.maximum(r.triangle, 0)] & r.mask
    assert on_zero.any() and (u.visibility[on_zero] == 0).all()
    view = render(fit.vertices, Degenerate, fit.camera, colours=np.ones((V.shape[0], 3)))
    assert np.isfinite(view.image).all()


def test_external_occlusion_mask(model):
    r = rasterize_uv(model, size=256)
    fit = posed_fit(model, size=256)
    image = np.full((256, 256, 3), 200, np.uint8)
    base = unwrap_details(image, fit, model, raster=r)
    mask = np.zeros((256, 256), bool)
    mask[:, :128] = True  # the left half of the image is covered
    u = unwrap_details(image, fit, model, raster=r, occlusion=mask)
    left = (u.pixel[..., 0] < 127) & r.mask & base.visible
    right = (u.pixel[..., 0] > 129) & r.mask
    assert left.sum() > 1000 and (u.visibility[left] == 0).all()
    np.testing.assert_allclose(u.visibility[right], base.visibility[right])
    full = unwrap(image, fit, model, raster=r, occlusion=np.ones((256, 256)))[1]
    assert (full == 0).all()
    with pytest.raises(InputError):
        unwrap(image, fit, model, raster=r, occlusion=np.ones((10, 10)))


def test_colour_spaces_and_photo_object(model):
    r = rasterize_uv(model, size=128)
    fit = posed_fit(model, size=128)
    image = np.full((128, 128, 3), 128, np.uint8)
    t_srgb, m = unwrap(image, fit, model, raster=r)
    t_lin, _ = unwrap(image, fit, model, raster=r, colour_space="linear")
    seen = m > 0
    np.testing.assert_allclose(t_srgb[seen], 128 / 255, atol=1e-5)
    np.testing.assert_allclose(t_lin[seen], ((128 / 255 + 0.055) / 1.055) ** 2.4, atol=1e-5)
    photo = facegeo.Photo(image=image, path="x.png", scale=1.0, original_size=(128, 128))
    np.testing.assert_array_equal(unwrap(photo, fit, model, raster=r)[0], t_srgb)
    with pytest.raises(InputError):
        unwrap(image, fit, model, raster=r, colour_space="xyz")
    with pytest.raises(InputError):
        unwrap(np.zeros((64, 64, 3), np.uint8), fit, model, raster=r)


def test_render_buffers(model):
    fit = posed_fit(model, yaw=10, size=128)
    colours = np.tile(np.array([[0.2, 0.4, 0.6]], np.float32), (model.n_vertices, 1))
    view = render(fit.vertices, model, fit.camera, colours=colours, background=(1.0, 0.0, 0.0))
    assert view.image.shape == (128, 128, 3)
    assert np.abs(view.image[view.mask] - [0.2, 0.4, 0.6]).max() < 1e-5
    assert (view.image[~view.mask] == [1, 0, 0]).all()
    assert np.isinf(view.depth[~view.mask]).all() and (view.triangle[~view.mask] == -1).all()
    assert 500 < view.depth[view.mask].min() < view.depth[view.mask].max() < 900
    np.testing.assert_allclose(view.barycentric[view.mask].sum(-1), 1, atol=1e-5)
    assert view.uv is not None and (view.uv[view.mask] >= 0).all()
    plain = render(fit.vertices, model, fit.camera)
    assert plain.image is None and (plain.mask == view.mask).all()
    # the depth buffer is the nearest surface: compare with ray casting at the pixel centres
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(fit.vertices), o3d.core.Tensor(model.triangles.astype(np.uint32)))
    j, i = np.mgrid[0:128, 0:128]
    d = np.stack([(i + 0.5 - 64) / fit.camera.focal, -(j + 0.5 - 64) / fit.camera.focal, -np.ones_like(i, float)], -1)
    rays = np.concatenate([np.zeros_like(d), d], -1).reshape(-1, 6).astype(np.float32)
    t_hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().reshape(128, 128)
    hit = np.isfinite(t_hit)
    assert (hit == view.mask).mean() > 0.998
    both = hit & view.mask
    np.testing.assert_allclose(view.depth[both], t_hit[both], rtol=1e-4)
    with pytest.raises(InputError):
        render(np.zeros((5, 3)), model, fit.camera)


def test_sky_visibility_of_a_plane_and_of_the_floor_of_a_square_well():
    """A flat plane sees the whole sky; the centre of a square well's floor (half-side s, depth
    h) sees it through the opening only: the view factor of a differential area to a parallel
    coaxial square, (4/π) · x/√(1+x²) · atan(x/√(1+x²)) with x = s/h (Howell's catalogue of
    configuration factors, B-3, summed over the four quadrants; 0.55 for s = h)."""
    from facegeo.uv import sky_visibility
    from facegeo.uv.renderer import SKY_OFFSET_MM

    grid = np.stack(np.meshgrid(np.linspace(-50, 50, 5), np.linspace(-50, 50, 5)), -1).reshape(-1, 2)
    plane = np.concatenate([grid, np.zeros((25, 1))], 1)
    quads = [(r * 5 + c, r * 5 + c + 1, (r + 1) * 5 + c + 1, (r + 1) * 5 + c) for r in range(4) for c in range(4)]
    triangles = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    np.testing.assert_allclose(sky_visibility(plane, triangles), 1.0)

    s = h = 100.0
    floor = [(0, 0, 0), (-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)]
    top = [(-s, -s, h), (s, -s, h), (s, s, h), (-s, s, h)]
    vertices = np.array(floor + top, np.float64)
    fan = [(0, 1, 2), (0, 2, 3), (0, 3, 4), (0, 4, 1)]  # counter-clockwise from above: the floor faces +z
    walls = [t for a in range(4) for t in ((1 + a, 1 + (a + 1) % 4, 5 + (a + 1) % 4), (1 + a, 5 + (a + 1) % 4, 5 + a))]
    x = s / (h - SKY_OFFSET_MM)  # the rays start SKY_OFFSET_MM above the floor
    root = np.sqrt(1 + x * x)
    expected = 4.0 / np.pi * (x / root) * np.arctan(x / root)
    sky = sky_visibility(vertices, np.array(fan + walls), directions=4096)
    assert sky[0] == pytest.approx(expected, abs=0.01)
    assert sky_visibility(vertices, np.array(fan + walls), directions=4096, at=np.array([0, 5])) == pytest.approx(sky[[0, 5]])
    with pytest.raises(InputError, match="directions"):
        sky_visibility(vertices, np.array(fan + walls), directions=0)
    with pytest.raises(InputError, match="vertices"):
        sky_visibility(vertices[:, :2], np.array(fan + walls))
