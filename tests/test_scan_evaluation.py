"""The NoW-style scan evaluation's maths (benchmarks/scan_evaluation.py) on known answers; no
Blender, no downloads."""

import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from facegeo.camera import rotation_from_euler

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from scan_evaluation import (  # noqa: E402
    REGIONS, Prediction, evaluate, outer_surface, prepare_scan, region_of_samples, relative_rotation_error,
    similarity_transform, surface_distances,
)


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


@pytest.fixture(scope="module")
def face(model):
    """The ICT mean shape as a 'scan' with its 68 landmarks, and its reference (coarse samples)."""
    vertices = model.mean_shape.astype(np.float64)
    ids = model.landmark_indices[:68]
    reference = prepare_scan(vertices, model.triangles, vertices[ids], area_per_sample_mm2=6.0)
    return vertices, model.triangles, ids, reference


def test_similarity_transform_recovers_a_known_transform():
    rng = np.random.default_rng(0)
    source = rng.normal(size=(20, 3)) * 30
    rotation = _random_rotation(rng)
    target = 1.37 * source @ rotation.T + [4.0, -2.0, 9.0]
    scale, r, t = similarity_transform(source, target)
    assert scale == pytest.approx(1.37, abs=1e-12)
    np.testing.assert_allclose(r, rotation, atol=1e-12)
    np.testing.assert_allclose(t, [4.0, -2.0, 9.0], atol=1e-10)
    assert similarity_transform(source, target, with_scale=False)[0] == 1.0


def test_a_mesh_moved_by_a_similarity_has_zero_error_against_itself(face):
    vertices, triangles, ids, reference = face
    rng = np.random.default_rng(1)
    moved = 0.8 * vertices @ _random_rotation(rng).T + [120.0, -40.0, 600.0]
    result = evaluate(Prediction(moved, triangles, ids), reference)
    assert result["alignment"]["scale"] == pytest.approx(1.25, rel=1e-9)
    assert result["mean"] < 1e-4 and result["rmse"] < 1e-4
    assert all(abs(d) < 1e-3 for d in result["depth"].values())
    assert result["n_samples"] > 1000


def test_a_known_offset_of_a_sphere_gives_the_known_distance():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=80.0)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=80.0)  # coarse: its vertices lie on the sphere
    points = inner.vertices
    bigger = sphere.vertices * (82.0 / 80.0)
    distance, closest = surface_distances(bigger, sphere.faces, points)
    # the tessellated sphere of radius 82 lies within its sagitta (< 0.02 mm) inside the true one
    np.testing.assert_allclose(distance, 2.0, atol=0.02)
    np.testing.assert_allclose(np.linalg.norm(closest, axis=1), 82.0, atol=0.02)


def test_a_chin_pushed_forward_shows_as_a_positive_chin_depth_error(face):
    vertices, triangles, ids, reference = face
    # a bump of +3 mm along the face's forward axis on the chin's front, flat within 8 mm of the probe
    local = (vertices - reference.landmarks[30]) @ reference.frame.T
    radial = np.linalg.norm(local[:, :2] - reference.depth_points[2], axis=1)
    front = local[:, 2] > local[ids[57], 2] - 25.0
    weight = np.clip((16.0 - radial) / 8.0, 0.0, 1.0) * front
    pushed = vertices + 3.0 * weight[:, None] * reference.frame[2]
    result = evaluate(Prediction(pushed, triangles, ids), reference)
    assert result["depth"]["chin"] == pytest.approx(3.0, abs=0.3)
    assert abs(result["depth"]["upper lip"]) < 0.3
    assert result["regions"]["chin"] > 0.15 and result["regions"]["forehead"] < 0.1


def test_regions_hold_the_landmarks_they_are_named_after(face, model):
    vertices, triangles, ids, reference = face
    lm = reference.landmarks
    up = reference.frame[1]
    points = np.stack([lm[30], lm[62], 0.5 * (lm[19] + lm[24]) + 25.0 * up, 0.5 * (lm[41] + lm[48]), 0.5 * (lm[46] + lm[54])])
    normals = np.tile(reference.frame[2], (len(points), 1))
    regions = [REGIONS[k] if k >= 0 else None for k in region_of_samples(points, normals, lm, reference.frame)]
    assert regions == ["nose", "mouth", "forehead", "right cheek", "left cheek"]
    backwards = region_of_samples(points, -normals, lm, reference.frame)
    assert np.all(backwards == -1)
    assert set(np.unique(reference.regions)) == set(range(-1, len(REGIONS)))
    upper, lower, chin = reference.depth_points  # face-frame (x, y) of the depth probes
    assert upper[1] > lower[1] > chin[1] + 10.0  # the chin probe lies well below the lower lip


def test_relative_rotation_error_is_exact_on_a_synthetic_rotation():
    rng = np.random.default_rng(2)
    scan_frame, model_frame = _random_rotation(rng), _random_rotation(rng)
    true_frontal, fit_frontal = scan_frame, model_frame
    true_view = rotation_from_euler(20.0, -10.0, 5.0) @ scan_frame
    fit_view = rotation_from_euler(23.0, -10.0, 5.0) @ model_frame
    error = relative_rotation_error(fit_view, fit_frontal, true_view, true_frontal)
    assert error["yaw"] == pytest.approx(3.0, abs=1e-9)
    assert error["pitch"] == pytest.approx(0.0, abs=1e-9) and error["roll"] == pytest.approx(0.0, abs=1e-9)
    assert error["angle"] == pytest.approx(3.0, abs=1e-6)
    same = relative_rotation_error(true_view, true_frontal, true_view, true_frontal)
    assert max(abs(v) for v in same.values()) < 1e-6


def test_a_shells_inner_surface_is_not_its_outer_surface():
    """A head-like shell (sphere of 80 mm) with a surface inside it (40 mm) and a dent: the
    points on the inner sphere are enclosed, those on the outer one (in the dent too) are not,
    whichever way the triangles wind."""
    outer = trimesh.creation.icosphere(subdivisions=4, radius=80.0)
    dent = outer.vertices[:, 2] > 70.0
    outer.vertices[dent] *= 0.85  # a concavity (a nostril's or an ear's fold, say)
    inner = trimesh.creation.icosphere(subdivisions=3, radius=40.0)
    inner.faces = inner.faces[:, ::-1]  # wound the other way
    vertices = np.concatenate([outer.vertices, inner.vertices])
    triangles = np.concatenate([outer.faces, inner.faces + len(outer.vertices)])
    mesh = trimesh.Trimesh(vertices, triangles, process=False)
    points = mesh.triangles_center
    free = outer_surface(vertices, triangles, points, mesh.face_normals)
    on_outer = np.arange(len(triangles)) < len(outer.faces)
    assert free[on_outer].all() and not free[~on_outer].any()
