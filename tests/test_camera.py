"""Camera, projection and rotations against analytic answers and OpenCV."""

import math

import cv2
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from facegeo.errors import InputError
from facegeo.camera import (
    OPENCV_FROM_OPENGL,
    Camera,
    euler_from_rotation,
    project,
    to_pixels,
    rotation_from_axis_angle,
    rotation_from_euler,
)

CAM = Camera(focal=1000.0, cx=320.0, cy=240.0, width=640, height=480)


def test_point_on_axis_projects_to_principal_point():
    uv = project(np.array([[0.0, 0.0, 0.0]]), np.eye(3), np.array([0.0, 0.0, -500.0]), CAM)
    np.testing.assert_allclose(uv, [[320.0, 240.0]])


def test_up_is_up_and_right_is_right():
    # +Y (up) goes to smaller rows; +X to larger columns; distance halves the offset.
    uv = project(np.array([[10.0, 10.0, 0.0]]), np.eye(3), np.array([0.0, 0.0, -500.0]), CAM)
    np.testing.assert_allclose(uv, [[320.0 + 20.0, 240.0 - 20.0]])
    far = project(np.array([[10.0, 10.0, 0.0]]), np.eye(3), np.array([0.0, 0.0, -1000.0]), CAM)
    np.testing.assert_allclose(far, [[330.0, 230.0]])


def test_to_pixels_is_project_without_pose_and_keeps_the_dtype():
    pts = np.random.default_rng(1).normal(scale=60.0, size=(50, 3)) + [0.0, 0.0, -600.0]
    expected = project(pts, np.eye(3), np.zeros(3), CAM)
    np.testing.assert_array_equal(to_pixels(pts, CAM), expected)
    single = to_pixels(pts.astype(np.float32), CAM)
    assert single.dtype == np.float32
    np.testing.assert_allclose(single, expected, rtol=1e-6)
    behind = to_pixels(np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 5.0]]), CAM)
    assert np.isfinite(behind).all()  # depth clamped, never a division by zero


@settings(max_examples=30, deadline=None)
@given(
    st.tuples(*[st.floats(-60, 60)] * 3),
    st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-900, -300)),
)
def test_matches_opencv_projectpoints(angles, t):
    r = rotation_from_euler(*angles)
    pts = np.random.default_rng(0).normal(scale=60.0, size=(20, 3))
    ours = project(pts, r, np.array(t), CAM)
    # scipy's matrix -> rotation vector is accurate near the identity, cv2.Rodrigues is not
    rvec = Rotation.from_matrix(OPENCV_FROM_OPENGL @ r).as_rotvec()
    theirs, _ = cv2.projectPoints(pts, rvec, OPENCV_FROM_OPENGL @ np.array(t), CAM.matrix(), None)
    np.testing.assert_allclose(ours, theirs.reshape(-1, 2), rtol=1e-7, atol=1e-6)


def test_torch_projection_is_differentiable_and_batched():
    pts = torch.randn(2, 5, 3, dtype=torch.float64, requires_grad=True)
    r = torch.eye(3, dtype=torch.float64).expand(2, 3, 3)
    t = torch.tensor([[0.0, 0.0, -400.0], [1.0, 2.0, -500.0]], dtype=torch.float64)
    out = project(pts, r, t, CAM)
    assert out.shape == (2, 5, 2)
    assert torch.autograd.gradcheck(lambda p: project(p, r, t, CAM), (pts,))


def test_behind_camera_stays_finite():
    uv = project(np.array([[0.0, 0.0, 10.0]]), np.eye(3), np.zeros(3), CAM)
    assert np.all(np.isfinite(uv))


@settings(max_examples=50, deadline=None)
@given(st.tuples(*[st.floats(-3.0, 3.0)] * 3))
def test_rodrigues_matches_scipy(w):
    from scipy.spatial.transform import Rotation

    ours = rotation_from_axis_angle(torch.tensor(w, dtype=torch.float64)).numpy()
    np.testing.assert_allclose(ours, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)


def test_rodrigues_gradient_at_zero_is_the_cross_product_matrix():
    w = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    jac = torch.autograd.functional.jacobian(rotation_from_axis_angle, w)
    assert torch.all(torch.isfinite(jac))
    # d R / d w_x at 0 is [e_x]_×
    np.testing.assert_allclose(jac[..., 0].numpy(), [[0, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-9)


@settings(max_examples=50, deadline=None)
@given(st.floats(-89, 89), st.floats(-89, 89), st.floats(-179, 179))
def test_euler_round_trip(yaw, pitch, roll):
    r = rotation_from_euler(yaw, pitch, roll)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(euler_from_rotation(r), (yaw, pitch, roll), atol=1e-7)


def test_positive_yaw_turns_nose_to_viewer_right():
    nose = rotation_from_euler(30, 0, 0) @ np.array([0.0, 0.0, 100.0])
    assert nose[0] == pytest.approx(100 * math.sin(math.radians(30)))


def test_camera_for_image_and_scaling():
    cam = Camera.for_image(800, 600, fov_deg=90.0)
    assert cam.focal == pytest.approx(400.0)
    assert (cam.cx, cam.cy) == (400.0, 300.0)
    half = cam.scaled(0.5)
    assert half.focal == pytest.approx(200.0)
    assert (half.cx, half.width, half.height) == (200.0, 400, 300)
    with pytest.raises(InputError, match="^<camera>: focal: expected a finite focal length > 0 in pixels, found -1.0$"):
        Camera(-1.0, 0, 0, 10, 10)
    with pytest.raises(InputError, match="principal point"):
        Camera(100.0, float("nan"), 0, 10, 10)
    with pytest.raises(InputError, match="image size: expected a positive width and height in pixels, found 0x10"):
        Camera(100.0, 0, 0, 0, 10)


def test_pixels_jacobian_is_the_projections_slope_and_cross_matrices_cross():
    from facegeo.camera import cross_matrices, pixels_jacobian

    rng = np.random.default_rng(0)
    points = rng.normal(0, 60, (20, 3)) + np.array([0.0, 0.0, -700.0])
    camera = Camera(focal=1200.0, cx=320.0, cy=240.0, width=640, height=480)
    jac = pixels_jacobian(points, camera.focal)
    for axis in range(3):
        step = np.zeros(3)
        step[axis] = 1e-4
        numeric = (to_pixels(points + step, camera) - to_pixels(points - step, camera)) / 2e-4
        assert np.allclose(jac[:, :, axis], numeric, rtol=1e-6, atol=1e-6)
    other = rng.normal(0, 1, (20, 3))
    assert np.allclose((cross_matrices(points) @ other[:, :, None])[..., 0], np.cross(points, other))
    assert cross_matrices(points.astype(np.float32)).dtype == np.float32
