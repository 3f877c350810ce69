"""Ambient occlusion against the view factor of an open box (numerical quadrature), on a plane,
and under a rotation of the mesh."""

import numpy as np
import pytest
from scipy import integrate
from scipy.spatial.transform import Rotation

from facegeo.uv.sky_visibility import AO_OFFSET_MM, ambient_occlusion, hemisphere_directions


def grid(n: int, half: float) -> tuple[np.ndarray, np.ndarray]:
    """A flat (2n + 1)² vertex grid on z = 0 over [−half, half]², triangles counter-clockwise
    seen from +Z; the centre vertex is index (2n + 1)² // 2."""
    t = np.linspace(-half, half, 2 * n + 1)
    x, y = np.meshgrid(t, t)
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    m = 2 * n + 1
    a = (np.arange(m - 1)[:, None] * m + np.arange(m - 1)[None, :]).ravel()
    triangles = np.concatenate([np.stack([a, a + 1, a + m + 1], 1), np.stack([a, a + m + 1, a + m], 1)])
    return vertices, triangles


def open_box(half: float, height: float) -> tuple[np.ndarray, np.ndarray, int]:
    """A box without a lid: a floor grid over [−half, half]² at z = 0 and four walls up to
    ``height``. Returns vertices, triangles and the floor's centre vertex."""
    floor, floor_tri = grid(4, half)
    corners = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    walls, wall_tri = [], []
    for k in range(4):
        (x0, y0), (x1, y1) = corners[k], corners[(k + 1) % 4]
        base = len(floor) + 4 * k
        walls += [[x0, y0, 0.0], [x1, y1, 0.0], [x1, y1, height], [x0, y0, height]]
        wall_tri += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    vertices = np.concatenate([floor, np.array(walls)])
    return vertices, np.concatenate([floor_tri, np.array(wall_tri)]), len(floor) // 2


def test_directions_are_unit_cosine_weighted_and_in_the_upper_hemisphere():
    d = hemisphere_directions(4096)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    assert d[:, 2].min() > 0
    # cosine-weighted: E[cos θ] = 2/3, E[cos² θ] = 1/2, no preferred azimuth
    assert d[:, 2].mean() == pytest.approx(2.0 / 3.0, abs=2e-3)
    assert (d[:, 2] ** 2).mean() == pytest.approx(0.5, abs=2e-3)
    np.testing.assert_allclose(d[:, :2].mean(axis=0), 0.0, atol=2e-3)


@pytest.mark.parametrize("half, height", [(10.0, 10.0), (10.0, 30.0), (20.0, 5.0)])
def test_floor_of_an_open_box_sees_the_view_factor_of_its_opening(half, height):
    """The centre of the floor sees the sky through the square opening: the view factor
    ∫∫ h² / (π (x² + y² + h²)²) dx dy over it (quadrature, not rays), h measured from where the
    rays start (AO_OFFSET_MM above the floor)."""
    vertices, triangles, centre = open_box(half, height)
    h = height - AO_OFFSET_MM
    expected, _ = integrate.dblquad(lambda y, x: h**2 / (np.pi * (x * x + y * y + h**2) ** 2), -half, half, -half, half)
    ao = ambient_occlusion(vertices, triangles, directions=2048)
    assert ao[centre] == pytest.approx(expected, abs=0.01)
    assert ambient_occlusion(vertices, triangles)[centre] == pytest.approx(expected, abs=0.04)  # the default 64 rays


def test_a_plane_is_open_sky_and_a_rotation_changes_nothing():
    vertices, triangles = grid(6, 30.0)
    np.testing.assert_array_equal(ambient_occlusion(vertices, triangles), 1.0)
    box, box_triangles, _ = open_box(10.0, 15.0)
    rotated = box @ Rotation.from_euler("xyz", [30, -50, 110], degrees=True).as_matrix().T + [5.0, -3.0, 40.0]
    a, b = ambient_occlusion(box, box_triangles, directions=1024), ambient_occlusion(rotated, box_triangles, directions=1024)
    inner = (np.abs(box[:, :2]).max(axis=1) < 9.0) & (box[:, 2] == 0)  # the floor off its edges (on an edge a ray starts on a wall)
    assert inner.sum() == 49
    np.testing.assert_allclose(a[inner], b[inner], atol=0.02)
    assert a[inner].min() < 0.5  # the floor is well occluded, so the comparison is not of ones


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="ambient_occlusion"):
        ambient_occlusion(np.zeros((4, 2)), np.zeros((1, 3), int))
