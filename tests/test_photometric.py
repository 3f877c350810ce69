"""The photometric stage recovers known SH lighting from a synthetic rendering."""

import cv2
import numpy as np
import pytest
import torch

from facegeo import Camera, load_model, project
from facegeo.camera import rotation_from_euler
from facegeo.colour import (channel_max, channel_min, channel_sum, linear_to_srgb, linear_to_srgb_torch, srgb8_to_linear, srgb_to_linear,
                            srgb_to_linear_slope, srgb_to_linear_torch)
from facegeo.fitting import fit_landmarks
from facegeo.fitting.photometric import fit_photometric
from facegeo.skin_mask import skin_vertex_mask
from facegeo.lighting import sh_irradiance
from facegeo.visibility import vertex_visibility


def render_flat(vertices_cam, triangles, colours_linear, camera):
    """Painter's-algorithm rendering (far to near) of flat-shaded triangles: (H, W, 3) uint8 sRGB."""
    uv = project(vertices_cam.astype(np.float64), np.eye(3), np.zeros(3), camera)
    depth = -vertices_cam[triangles].mean(axis=1)[:, 2]
    image = np.zeros((camera.height, camera.width, 3), np.float32)
    for f in np.argsort(-depth):
        tri = triangles[f]
        poly = np.round((uv[tri] - 0.5) * 16).astype(np.int32)
        cv2.fillPoly(image, [poly], colours_linear[tri].mean(axis=0).tolist(), cv2.LINE_8, 4)
    return np.clip(np.round(linear_to_srgb(image) * 255), 0, 255).astype(np.uint8)


def test_srgb_round_trip_and_known_values():
    x = np.linspace(0, 1, 101, dtype=np.float32)
    np.testing.assert_allclose(srgb_to_linear(linear_to_srgb(x)), x, atol=1e-6)
    # sRGB 0.5 is linear 0.2140; linear 0.0031308 is the knee at sRGB 0.04045
    assert float(srgb_to_linear(np.float32(0.5))) == pytest.approx(0.21404, abs=1e-5)
    assert float(linear_to_srgb(np.float32(0.0031308))) == pytest.approx(0.04045, abs=1e-5)


def test_8_bit_codes_decode_by_table_to_the_curves_numbers():
    codes = np.random.default_rng(3).integers(0, 256, (37, 41, 3)).astype(np.uint8)
    codes.reshape(-1)[:256] = np.arange(256)  # every code at least once
    table = srgb8_to_linear(codes)
    assert table.dtype == np.float32 and table.shape == codes.shape
    np.testing.assert_array_equal(table.view(np.uint32), srgb_to_linear(codes.astype(np.float32) / 255.0).view(np.uint32))
    assert float(srgb8_to_linear(np.array([128], np.uint8))[0]) == pytest.approx(0.21586, abs=1e-5)  # 128/255 = 0.50196
    with pytest.raises(TypeError, match="uint8"):
        srgb8_to_linear(codes.astype(np.uint16))


def test_srgb_twins_agree_with_the_numpy_curves():
    x = np.linspace(-0.1, 1.2, 263)
    lin, slope = srgb_to_linear_slope(x)  # float64, clipped to [0, 1]
    np.testing.assert_allclose(lin, srgb_to_linear(np.clip(x, 0, 1)), atol=1e-6)
    h = 1e-7
    inner = (x > 0.01) & (x < 0.99) & (np.abs(x - 0.04045) > 1e-3)
    numeric = (srgb_to_linear_slope(x + h)[0] - srgb_to_linear_slope(x - h)[0]) / (2 * h)
    np.testing.assert_allclose(slope[inner], numeric[inner], rtol=1e-6)
    t = torch.from_numpy(x)
    np.testing.assert_allclose(srgb_to_linear_torch(t).numpy()[x <= 1], srgb_to_linear(x[x <= 1]), atol=1e-6)
    np.testing.assert_allclose(linear_to_srgb_torch(t).numpy(), linear_to_srgb(x), atol=1e-6)
    unclipped = linear_to_srgb_torch(t, clip=False).numpy()
    np.testing.assert_allclose(unclipped[(x >= 0) & (x <= 1)], linear_to_srgb(x[(x >= 0) & (x <= 1)]), atol=1e-6)
    assert unclipped[-1] > 1.0 and unclipped[0] == pytest.approx(12.92 * -0.1)
    g = torch.tensor([0.02, 0.5], dtype=torch.float64, requires_grad=True)
    srgb_to_linear_torch(g).sum().backward()
    np.testing.assert_allclose(g.grad.numpy(), srgb_to_linear_slope(g.detach().numpy())[1], rtol=1e-12)


def test_channel_reductions_equal_numpys():
    """The per-channel max, min and sum are NumPy's reductions over the last axis, bit for bit
    (a bool array's sum through its uint8 view)."""
    rgb = np.random.default_rng(0).random((5, 7, 3), dtype=np.float32)
    np.testing.assert_array_equal(channel_max(rgb), rgb.max(axis=-1, keepdims=True))
    np.testing.assert_array_equal(channel_min(rgb), rgb.min(axis=-1))
    np.testing.assert_array_equal(channel_sum(rgb), rgb.sum(axis=-1))
    flags = rgb > 0.5
    np.testing.assert_array_equal(channel_sum(flags.view(np.uint8)), flags.sum(axis=-1))


def test_recovers_sh_lighting_of_a_rendered_face():
    model = load_model()
    camera = Camera.for_image(320, 320)
    rotation = rotation_from_euler(15.0, -5.0, 0.0)
    translation = np.array([0.0, 0.0, -450.0])
    shape = model.shape().numpy()
    landmarks = project(shape[model.landmark_indices].astype(np.float64), rotation, translation, camera)
    result = fit_landmarks(model, landmarks, camera)
    gamma = np.zeros((3, 9), np.float32)
    gamma[:, 0] = [0.9, 0.7, 0.6]  # skin-coloured ambient
    gamma[:, 2] = [0.35, 0.3, 0.25]  # light from the camera side
    gamma[:, 3] = [-0.15, -0.1, -0.1]  # and from the right
    normals = model.vertex_normals(torch.from_numpy(result.vertices))
    colours = (model.albedo() * sh_irradiance(normals, torch.from_numpy(gamma))).numpy()
    image = render_flat(result.vertices, model.triangles, colours, camera)
    result = fit_photometric(model, result, srgb_to_linear(image.astype(np.float32) / 255.0))
    info = result.info["photometric"]
    assert info["skin_vertices_used"] > 1000
    # Over the visible half of the sphere the bands 1, n_z and 3n_z² − 1 are nearly collinear, so
    # the coefficients themselves are not identifiable; the irradiance they produce is.
    visible = vertex_visibility(result.vertices, model.triangles, normals.numpy(), camera) & skin_vertex_mask(model)
    fitted = sh_irradiance(normals[visible], torch.from_numpy(result.gamma)).numpy()
    truth = sh_irradiance(normals[visible], torch.from_numpy(gamma)).numpy()
    assert np.median(np.abs(fitted / truth - 1)) < 0.02
    assert np.percentile(np.abs(fitted / truth - 1), 95) < 0.06
    assert info["rms_linear"] < 0.02


def test_visibility_hides_the_back_of_the_head():
    model = load_model()
    camera = Camera.for_image(256, 256)
    vertices = model.mean_shape + np.array([0.0, 0.0, -500.0], np.float32)
    normals = model.vertex_normals(torch.from_numpy(vertices)).numpy()
    visible = vertex_visibility(vertices, model.triangles, normals, camera)
    nose_tip = model.landmark_indices[30]
    assert visible[nose_tip]
    back = model.mean_shape[:, 2] < np.percentile(model.mean_shape[:, 2], 5)
    assert not visible[back].any()
    assert skin_vertex_mask(model)[nose_tip]
