"""The dense term of the landmark fit, the occluding contour and the focal of an unknown lens
(synthetic instances of the bundled model: known answers)."""

import dataclasses

import numpy as np
import pytest
import torch

from facegeo import Camera, project
from facegeo.camera import euler_from_rotation, rotation_from_euler
from facegeo.fitting import fit_landmarks
from facegeo.fitting.camera_estimate import ASSUMED_SUBJECT_DISTANCE_MM, camera_for_face
from facegeo.fitting.dense_term import DenseSettings, dense_surface_points, landmark_weights_with_dense
from facegeo.fitting.landmark_fit import rotation_step
from facegeo.fitting.landmark_problem import LandmarkProblem, SurfacePoints, silhouette_of
from facegeo.landmarks.dense import DenseCorrespondence, points_on_mesh
from facegeo.landmarks.scheme import CHIN, JAW, LANDMARK_WEIGHTS, inter_ocular_distance
from test_fitting import CAMERA, realistic_delta, similarity_rms


def _random_correspondence(model, rng, count=400):
    """``count`` points on random face-region triangles (the test needs known surface points, not
    MediaPipe's: the dense term must recover a face from any surface points it is given)."""
    tris = np.asarray(model.triangles)
    face = model.face_mask[tris].all(axis=1) & (model.mean_shape[tris][:, :, 2].min(axis=1) > 20)
    triangle = rng.choice(np.flatnonzero(face), size=count, replace=False)
    bary = rng.dirichlet(np.ones(3), size=count)
    return DenseCorrespondence(triangle=triangle.astype(np.int32), barycentric=bary.astype(np.float32),
                               transfer_error_mm=np.full(count, 0.5, np.float32), contour=np.zeros(count, bool),
                               vertex_ids=tris[triangle], source="test")


def _face(model, rng, yaw, pitch=5.0, sigma=0.7):
    alpha = rng.normal(0, sigma, model.n_id).astype(np.float32)
    delta = realistic_delta(model, rng, 0.3)
    rotation = rotation_from_euler(yaw, pitch, 2.0)
    translation = np.array([10.0, -5.0, -600.0])
    shape = model.shape(torch.from_numpy(alpha), torch.from_numpy(delta)).numpy().astype(np.float64)
    return shape, rotation, translation


def test_surface_points_jacobian_matches_finite_differences(model):
    """The Jacobian with dense surface points (barycentric rows) equals central differences."""
    rng = np.random.default_rng(3)
    shape, rotation, translation = _face(model, rng, 20.0)
    corr = _random_correspondence(model, rng, 60)
    landmarks = project(shape[model.landmark_indices], rotation, translation, CAMERA)
    dense = project(points_on_mesh(shape, corr), rotation, translation, CAMERA)
    extra = SurfacePoints(dense, corr.vertex_ids, corr.barycentric, np.full(60, 0.3))
    problem = LandmarkProblem(model, landmarks, CAMERA, LANDMARK_WEIGHTS, extra)
    r0, t0 = rotation_from_euler(10, 5, -3), np.array([3.0, -4.0, -550.0])
    a0, d0 = rng.normal(0, 0.3, model.n_id), rng.uniform(0, 0.5, model.n_exp)
    problem.slide(r0, t0, a0, d0)
    n_id, n_exp, unit = 20, model.n_exp, 10.0

    def residuals(x):
        alpha = np.concatenate([a0[:n_id] + x[6 : 6 + n_id], a0[n_id:]])
        return problem.residuals(r0 @ rotation_step(x[:3]), t0 + unit * x[3:6], alpha, d0 + x[6 + n_id :])

    n, h = 6 + n_id + n_exp, 1e-6
    expected = np.stack([(residuals(h * e) - residuals(-h * e)) / (2 * h) for e in np.eye(n)], axis=1)
    np.testing.assert_allclose(problem.jacobian(r0, t0, a0, d0, n_id, n_exp, unit), expected, rtol=1e-6, atol=1e-9)


def test_dense_points_recover_the_identity_better_than_88_landmarks(model):
    """Noisy landmarks of a turned synthetic face: the fit with 400 dense surface points beside
    the 88 gets the 3-D face (similarity-aligned, face region) closer than the 88 alone."""
    rng = np.random.default_rng(11)
    shape, rotation, translation = _face(model, rng, 30.0)
    corr = _random_correspondence(model, rng)
    landmarks = project(shape[model.landmark_indices], rotation, translation, CAMERA)
    iod = inter_ocular_distance(landmarks)
    landmarks = landmarks + rng.normal(0, 0.02 * iod, landmarks.shape)
    dense = project(points_on_mesh(shape, corr), rotation, translation, CAMERA) + rng.normal(0, 0.02 * iod, (len(corr.triangle), 2))
    face = model.face_mask
    sparse = fit_landmarks(model, landmarks, CAMERA)
    extra = dense_surface_points(model, dense, corr, iod, DenseSettings())
    both = fit_landmarks(model, landmarks, CAMERA, weights=landmark_weights_with_dense(LANDMARK_WEIGHTS), surface_points=extra)
    error_sparse = similarity_rms(sparse.shape_vertices[face], shape[face])
    error_dense = similarity_rms(both.shape_vertices[face], shape[face])
    assert error_dense < 0.8 * error_sparse, (error_dense, error_sparse)
    assert both.info["surface_points"]["used"] == len(corr.triangle)
    yaw_error = abs(euler_from_rotation(both.rotation)[0] - euler_from_rotation(rotation)[0])
    assert yaw_error < 2.0


def test_dense_weights_follow_the_known_errors(model):
    """A point with a large transfer error or detector spread weighs less; NaN points nothing;
    the jaw's sliding points are left out when dense points are used, the chin kept."""
    rng = np.random.default_rng(1)
    corr = _random_correspondence(model, rng, 5)
    corr = dataclasses.replace(corr, transfer_error_mm=np.array([0.0, 10.0, 0.0, 0.0, 0.0], np.float32))
    points = rng.uniform(100, 200, (5, 2))
    points[4] = np.nan
    spread = np.array([0.0, 0.0, 20.0, 0.0, 0.0])
    w = dense_surface_points(model, points, corr, 60.0, DenseSettings(weight=0.5), spread).weights
    assert w[0] == pytest.approx(0.5) and w[3] == pytest.approx(0.5)
    assert w[1] < 0.1 and w[2] < 0.1 and w[4] == 0.0
    lw = landmark_weights_with_dense(LANDMARK_WEIGHTS)
    assert lw[CHIN] == LANDMARK_WEIGHTS[CHIN] and np.all(lw[JAW[JAW != CHIN]] == 0)
    np.testing.assert_array_equal(lw[17:], LANDMARK_WEIGHTS[17:])


def test_occluding_contour_follows_the_pose(model):
    """Frontal: the chin's contour vertex is the chin (within 6 mm of the chin landmark's height).
    Turned 40° (the subject's left cheek away from the camera): the far side's contour lies
    further inside the face than the frontal one, and it is the outermost in the image: the
    (hidden) frontal jaw line projects inside it."""
    sil = silhouette_of(model)
    mean = model.mean_shape.astype(np.float64)
    t = np.array([0.0, 0.0, -600.0])

    def picks(yaw):
        rotation = rotation_from_euler(yaw, 0.0, 0.0)
        cam = mean[sil.vertices] @ rotation.T + t
        return sil.vertices[sil.contour(cam, rotation)], rotation

    frontal, _ = picks(0.0)
    chin_y = mean[model.landmark_indices[CHIN], 1]
    lowest = mean[frontal, 1].min()
    assert abs(lowest - chin_y) < 6.0
    turned, rotation = picks(40.0)
    cam = mean @ rotation.T + t
    screen_x = cam[:, 0] / -cam[:, 2]
    far = turned[mean[turned, 0] > 0]  # the subject's left: +X
    far_frontal = frontal[mean[frontal, 0] > 0]
    assert np.median(np.abs(mean[far, 0])) < np.median(np.abs(mean[far_frontal, 0])) - 5.0
    assert screen_x[far].max() >= screen_x[model.landmark_indices[JAW]].max()
    assert mean[turned, 1].min() >= mean[model.landmark_indices[CHIN], 1] - 8.0 - 1e-6


def test_a_bin_facing_the_camera_to_its_end_gives_its_last_vertex(model):
    # the facing run of a bin that starts after its first vertex and reaches its end: the contour
    # vertex is the bin's last (it indexed past the bin: an IndexError on shuffled landmarks)
    silhouette = silhouette_of(model)
    sign = np.ones(len(silhouette.vertices))
    for members in silhouette.bins:
        sign[members[0]] = -1.0  # the innermost vertex faces away, every other one the camera
    positions = -sign[:, None] * silhouette.normals  # facing iff n · (−X) > 0
    picks = silhouette.contour(positions, np.eye(3))
    expected = [members[-1] for members in silhouette.bins if len(members) > 1]
    assert picks.tolist() == expected


def test_each_bins_contour_vertex_ends_its_first_facing_run(model):
    """On random facing patterns: a bin with a vertex facing the camera gives the last vertex of
    its first run of facing vertices (walking outwards); a bin facing away throughout gives none."""
    silhouette = silhouette_of(model)
    rng = np.random.default_rng(4)
    for _ in range(20):
        sign = np.where(rng.random(len(silhouette.vertices)) < rng.uniform(0.1, 0.9), 1.0, -1.0)
        positions = -sign[:, None] * silhouette.normals  # facing iff n · (−X) > 0
        expected = []
        for members in silhouette.bins:
            facing = sign[members] > 0
            if facing.any():
                start = int(np.argmax(facing))
                run = start
                while run + 1 < len(members) and facing[run + 1]:
                    run += 1
                expected.append(members[run])
        assert silhouette.contour(positions, np.eye(3)).tolist() == expected


def test_unknown_focal_puts_the_face_at_the_assumed_distance(model):
    """A camera of unknown focal gets f = d · iod_px / iod_mm; the fit then places the face near
    d; a known focal is kept as it is."""
    rng = np.random.default_rng(2)
    shape, rotation, translation = _face(model, rng, 0.0, sigma=0.0)
    translation = np.array([0.0, 0.0, -1600.0])
    truth = Camera(2000.0, 256.0, 256.0, 512, 512)
    landmarks = project(shape[model.landmark_indices], rotation, translation, truth)
    unknown = Camera.unknown_focal(512, 512)
    assert not unknown.focal_known
    estimated, note = camera_for_face(unknown, landmarks, model)
    assert note and estimated.cx == unknown.cx and not estimated.focal_known
    fitted = fit_landmarks(model, landmarks, estimated)
    assert abs(-fitted.translation[2] - ASSUMED_SUBJECT_DISTANCE_MM) < 0.1 * ASSUMED_SUBJECT_DISTANCE_MM
    kept, none = camera_for_face(truth, landmarks, model)
    assert kept is truth and none is None
    shifted = Camera.unknown_focal(512, 512, (300.0, 200.0))
    assert (shifted.cx, shifted.cy) == (300.0, 200.0)
