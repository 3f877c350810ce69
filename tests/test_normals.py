"""Vertex normals (facegeo.normals): the rule, its degenerate cases, and the torch twin against the
NumPy function (float64 reference)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from facegeo.normals import vertex_normals, vertex_normals_torch
from test_export_support import grid_mesh


def test_vertex_normals_sphere_and_orientation():
    s = trimesh.creation.icosphere(subdivisions=3, radius=50.0)
    n = vertex_normals(s.vertices, s.faces)
    radial = s.vertices / np.linalg.norm(s.vertices, axis=1, keepdims=True)
    assert np.min(np.sum(n * radial, axis=1)) > 0.999
    v, f, _, _ = grid_mesh(2)
    np.testing.assert_allclose(vertex_normals(v, f), np.tile([0, 0, 1.0], (len(v), 1)), atol=1e-12)


def test_vertex_normals_degenerate_cases_are_finite_unit():
    v, f, _, _ = grid_mesh(2)
    # vertex 9: only in a zero-area triangle (collinear with 0 and 1); vertex 10: in no triangle
    v = np.vstack([v, [[2.5, 0.0, 0.0]], [[99.0, 99.0, 99.0]]])
    f = np.vstack([f, [[0, 1, 9]]])
    n = vertex_normals(v, f)
    assert np.isfinite(n).all()
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(n[9], [0, 0, 1.0], atol=1e-12)  # from its neighbours
    np.testing.assert_allclose(n[10], [0, 0, 1.0])  # fallback +Z
    # all triangles degenerate: everything falls back, nothing is NaN
    flat = np.zeros((3, 3))
    assert np.isfinite(vertex_normals(flat, np.array([[0, 1, 2]]))).all()
    # opposite triangles cancelling (a zero-length sum)
    two = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    n2 = vertex_normals(two, np.array([[0, 1, 2], [0, 2, 1]]))
    assert np.isfinite(n2).all() and np.allclose(np.linalg.norm(n2, axis=1), 1.0)


def test_vertex_normals_match_the_model(model):
    V = model.mean_shape
    ours = vertex_normals(V, model.triangles)
    theirs = model.vertex_normals(torch.from_numpy(V)).numpy()
    np.testing.assert_allclose(ours, theirs, atol=1e-5)


def _degenerate_grid() -> tuple[np.ndarray, np.ndarray]:
    """A bumpy grid plus a vertex used only by a zero-area triangle and one used by none."""
    v, f, _, _ = grid_mesh(4)
    v[:, 2] = 0.3 * np.sin(v[:, 0]) * np.cos(0.7 * v[:, 1])
    v = np.vstack([v, [[2.5, 0.0, 0.0]], [[99.0, 99.0, 99.0]]])
    f = np.vstack([f, [[0, 1, len(v) - 2]]])
    v[len(v) - 2] = 0.5 * (v[0] + v[1])  # collinear with its triangle's other corners
    return v, f


@pytest.mark.parametrize("case", ["ict", "degenerate"])
def test_torch_twin_matches_numpy_reference(model, case):
    if case == "ict":
        v, f = model.mean_shape.astype(np.float64), model.triangles
    else:
        v, f = _degenerate_grid()
    reference = vertex_normals(v, f)
    assert reference.dtype == np.float64
    twin64 = vertex_normals_torch(torch.from_numpy(v), f)
    assert twin64.dtype == torch.float64
    np.testing.assert_allclose(twin64.numpy(), reference, atol=1e-12)
    twin32 = vertex_normals_torch(torch.from_numpy(v.astype(np.float32)), torch.from_numpy(f))
    assert twin32.dtype == torch.float32
    np.testing.assert_allclose(twin32.numpy(), reference, atol=1e-5)
    # batched: each element by its own rule (the second one mirrored, so its normals flip x)
    batch = torch.from_numpy(np.stack([v, v * [-1.0, 1.0, 1.0]]))
    mirrored = vertex_normals(v * [-1.0, 1.0, 1.0], f)
    out = vertex_normals_torch(batch, f)
    np.testing.assert_allclose(out[0].numpy(), reference, atol=1e-12)
    np.testing.assert_allclose(out[1].numpy(), mirrored, atol=1e-12)


def test_torch_twin_is_differentiable():
    v, f = _degenerate_grid()
    x = torch.from_numpy(v).requires_grad_(True)
    weights = torch.linspace(-1.0, 1.0, x.numel(), dtype=torch.float64).reshape(x.shape)
    (vertex_normals_torch(x, f) * weights).sum().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all() and x.grad.abs().max() > 0
    # the gradient of a clean vertex against central finite differences
    k, h = 7, 1e-6
    analytic = x.grad[k, 2].item()
    plus, minus = v.copy(), v.copy()
    plus[k, 2] += h
    minus[k, 2] -= h
    numeric = ((vertex_normals(plus, f) - vertex_normals(minus, f)) * weights.numpy()).sum() / (2 * h)
    assert abs(analytic - numeric) < 1e-6 * max(1.0, abs(numeric))


def test_batched_normals_equal_one_mesh_at_a_time(model):
    """(B, V, 3) meshes on one triangulation: the same normals as each mesh alone, the degenerate
    fallback (ring neighbours, then +Z) included."""
    shapes = model.mean_shape[None] + model.exp_basis[:6]
    batched = vertex_normals(shapes, model.triangles)
    assert batched.shape == shapes.shape
    np.testing.assert_allclose(batched, np.stack([vertex_normals(s, model.triangles) for s in shapes]), atol=1e-14)
    v, f, _, _ = grid_mesh(2)
    v = np.vstack([v, [[2.5, 0.0, 0.0]], [[99.0, 99.0, 99.0]]])
    f = np.vstack([f, [[0, 1, 9]]])
    meshes = np.stack([v, v * [1.0, 1.0, -1.0], v + np.random.default_rng(0).normal(0, 0.1, v.shape)])
    np.testing.assert_allclose(vertex_normals(meshes, f), np.stack([vertex_normals(x, f) for x in meshes]), atol=1e-14)
