"""The 468-point MediaPipe correspondence on the model's surface (facegeo.landmarks.dense).

Known answers: the canonical face mesh is mirror-symmetric (its mirror pairs are found from its
own geometry) and so is ICT's mean face, so mirror points must land on mirror positions; the
iBUG-68 points of the inner face are MediaPipe vertices pinned onto ICT's own landmark vertices by
the registration, so they must land near them; a model whose triangles are listed in another
order is the same surface, so registering against it must give the stored registration's points.
Thresholds are the measured values with a margin (measured: see the comments).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from facegeo.assets import asset_path
from facegeo.errors import InputError, ModelFileError
from facegeo.landmarks.dense import (
    DENSE_ASSET,
    DenseCorrespondence,
    load_dense_correspondence,
    points_on_mesh,
    points_on_mesh_torch,
    read_dense_correspondence,
    triangles_sha256,
)
from facegeo.landmarks.mediapipe_mesh import MEDIAPIPE_TO_IBUG68, N_MESH
from facegeo.landmarks.scheme import INNER_FACE
from facegeo.skin_mask import FACE_OVAL


@pytest.fixture(scope="module")
def stored() -> dict[str, np.ndarray]:
    with np.load(asset_path(DENSE_ASSET), allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


@pytest.fixture(scope="module")
def corr(model) -> DenseCorrespondence:
    found = load_dense_correspondence(model)
    assert found is not None
    return found


def _mean_points(model, triangle: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
    return np.einsum("pkc,pk->pc", model.mean_shape[model.triangles[triangle]].astype(np.float64), barycentric)


def test_file_layout_and_size(stored, model):
    assert asset_path(DENSE_ASSET).stat().st_size < 100_000
    assert stored["triangle"].dtype == np.int32 and stored["triangle"].shape == (N_MESH,)
    assert stored["barycentric"].dtype == np.float32 and stored["barycentric"].shape == (N_MESH, 3)
    assert stored["transfer_error_mm"].dtype == np.float32
    np.testing.assert_array_equal(stored["mediapipe_index"], np.arange(N_MESH))
    assert str(stored["model_triangles_sha256"]) == triangles_sha256(model.triangles)
    assert int(stored["n_vertices"]) == model.n_vertices
    # the contour flags are MediaPipe's face oval
    np.testing.assert_array_equal(np.flatnonzero(stored["contour"]), np.sort(FACE_OVAL))


def test_bundled_correspondence_is_valid(corr, model):
    assert corr.source == "bundled"
    assert corr.triangle.min() >= 0 and corr.triangle.max() < len(model.triangles)
    np.testing.assert_array_equal(corr.vertex_ids, model.triangles[corr.triangle])
    assert corr.barycentric.min() >= 0.0
    np.testing.assert_allclose(corr.barycentric.sum(1), 1.0, atol=1e-5)
    assert corr.transfer_error_mm.min() >= 1.0 and np.isfinite(corr.transfer_error_mm).all()
    # every point is on the face region (no ears-behind, neck or scalp-back triangles)
    assert model.face_mask[corr.vertex_ids].all()
    assert corr.contour.sum() == len(FACE_OVAL)


def test_mirror_points_land_on_mirror_positions(corr, stored, model):
    canonical = stored["canonical_vertices"].astype(np.float64)
    gap, mirror = cKDTree(canonical).query(canonical * [-1.0, 1.0, 1.0])
    assert gap.max() < 1e-4  # the canonical mesh is exactly symmetric
    assert (mirror[mirror] == np.arange(N_MESH)).all()
    points = points_on_mesh(model.mean_shape.astype(np.float64), corr)
    error = np.linalg.norm(points[mirror] * [-1.0, 1.0, 1.0] - points, axis=1)
    # measured: median 0.02 mm, 95th percentile 1.2 mm, max 2.8 mm (each point is refined on its
    # own, so a pair may move apart); the 28 midline points stay on the midline (|x| < 0.01 mm)
    assert np.median(error) < 0.5
    assert np.percentile(error, 95) < 2.5
    assert error.max() < 4.5
    midline = mirror == np.arange(N_MESH)
    assert midline.sum() == 28
    assert np.abs(points[midline, 0]).max() < 0.5


def test_ibug_points_land_near_the_models_landmarks(corr, stored, model):
    mean = model.mean_shape.astype(np.float64)
    ict = mean[model.landmark_indices[INNER_FACE]]
    # the registration pins them: measured max 0.57 mm (after the projection onto the surface)
    prior = _mean_points(model, stored["prior_triangle"], stored["prior_barycentric"].astype(np.float64))
    assert np.linalg.norm(prior[MEDIAPIPE_TO_IBUG68[INNER_FACE]] - ict, axis=1).max() < 1.0
    # refined, moved where the detector disagreed: measured median 2.2 mm, max 4.8 mm (nostrils)
    refined = points_on_mesh(mean, corr)[MEDIAPIPE_TO_IBUG68[INNER_FACE]]
    error = np.linalg.norm(refined - ict, axis=1)
    assert np.median(error) < 3.0
    assert error.max() < 6.5


def test_points_on_mesh_numpy_and_torch(corr, model):
    rng = np.random.default_rng(0)
    batch = model.mean_shape[None] + rng.normal(0, 1.0, (2, model.n_vertices, 3)).astype(np.float32)
    single = points_on_mesh(batch[0], corr)
    both = points_on_mesh(batch, corr)
    assert single.shape == (N_MESH, 3) and both.shape == (2, N_MESH, 3) and both.dtype == np.float32
    np.testing.assert_allclose(both[0], single, atol=1e-5)
    # a point is the barycentric blend of its triangle's corners
    i = 100
    expected = (batch[1][corr.vertex_ids[i]] * corr.barycentric[i][:, None]).sum(0)
    np.testing.assert_allclose(both[1, i], expected, atol=1e-5)
    vertices = torch.from_numpy(batch).requires_grad_(True)
    twin = points_on_mesh_torch(vertices, corr)
    np.testing.assert_allclose(twin.detach().numpy(), both, atol=1e-5)
    twin.sum().backward()  # each point's weights sum to 1: the gradient counts the points per vertex
    assert float(vertices.grad[0].sum()) == pytest.approx(3 * N_MESH, rel=1e-5)
    with pytest.raises(InputError):
        points_on_mesh(batch[0, :100], corr)


def test_another_model_is_refused_or_registered(model, stored):
    order = np.random.default_rng(0).permutation(len(model.triangles))
    other = dataclasses.replace(model, triangles=model.triangles[order], uv_triangles=model.uv_triangles[order])
    # an explicit file for another model: ModelFileError naming the checksum
    with pytest.raises(ModelFileError, match="model_triangles_sha256"):
        read_dense_correspondence(asset_path(DENSE_ASSET), other)
    # the loader: None without registration ...
    assert load_dense_correspondence(other, register=False) is None
    # ... else the registration against the other model's mean shape: the same surface, so the
    # stored registration's points (measured: 3e-6 mm apart)
    registered = load_dense_correspondence(other)
    assert registered is not None and registered.source == "registered"
    np.testing.assert_array_equal(registered.vertex_ids, other.triangles[registered.triangle])
    np.testing.assert_array_equal(registered.transfer_error_mm, stored["prior_error_mm"])
    prior = _mean_points(model, stored["prior_triangle"], stored["prior_barycentric"].astype(np.float64))
    again = points_on_mesh(other.mean_shape.astype(np.float64), registered)
    assert np.linalg.norm(again - prior, axis=1).max() < 0.05
