"""The fit's wrong-fit bar (issue 47): what it reads and what it refuses
(:func:`facegeo.fitting.checks.landmark_error_percent`, :func:`~facegeo.fitting.checks.check_fit`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from facegeo import Camera, fit_landmarks, project
from facegeo.assets import asset_path
from facegeo.camera import rotation_from_euler
from facegeo.errors import NoFaceError
from facegeo.fitting import fit
from facegeo.fitting.checks import (FOLLOWED_SHARE, MAX_LANDMARK_ERROR_PERCENT, check_fit, frontal_inter_ocular_distance,
                                    landmark_error_percent)
from facegeo.landmarks.detectors import get_detector
from facegeo.landmarks.scheme import INNER_FACE, JAW, LIP_POINTS, MOUTH, inter_ocular_distance
from facegeo.photo import load_photo

CAMERA = Camera.for_image(512, 512)


def synthetic_fit(model, yaw: float, distance_mm: float = 600.0):
    """A noiseless fit of the model's mean face turned by ``yaw`` degrees (the 88 projected
    landmark vertices as the detection), and the true frontal inter-ocular distance (px): focal ×
    the eye corners' distance (mm) / the depth of their midpoint (mm)."""
    shape = model.shape(torch.zeros(model.n_id), torch.zeros(model.n_exp)).numpy().astype(np.float64)
    rotation, translation = rotation_from_euler(yaw, 5.0, 0.0), np.array([0.0, 0.0, -distance_mm])
    landmarks = project(shape[model.landmark_indices], rotation, translation, CAMERA)
    eyes = shape[model.landmark_indices[[36, 45]]]
    depth = -float((eyes.mean(axis=0) @ rotation.T + translation)[2])
    return fit_landmarks(model, landmarks, CAMERA), CAMERA.focal * float(np.linalg.norm(eyes[0] - eyes[1])) / depth


@pytest.fixture(scope="module")
def turned(model):
    return synthetic_fit(model, 40.0, distance_mm=1500.0)[0]  # a small face turned 40°: about 30 px between the eyes


def with_errors(result, errors: np.ndarray):
    """``result`` whose per-point landmark errors (px) are ``errors`` (the RMS over them with it)."""
    used = np.isfinite(errors)
    return dataclasses.replace(result, landmark_errors_px=errors.astype(np.float32),
                               landmark_rms_px=float(np.sqrt(np.mean(errors[used] ** 2))))


def test_frontal_distance_does_not_shrink_with_the_turn(model):
    (front, front_truth), (side, side_truth) = synthetic_fit(model, 0.0), synthetic_fit(model, 60.0)
    assert frontal_inter_ocular_distance(front) == pytest.approx(front_truth, rel=0.01)
    assert frontal_inter_ocular_distance(side) == pytest.approx(side_truth, rel=0.01)
    # the detected distance is the frontal one facing the camera and shrinks as the face turns (cos 60° = 0.5)
    assert inter_ocular_distance(front.landmarks) == pytest.approx(front_truth, rel=0.02)
    assert inter_ocular_distance(side.landmarks) < 0.6 * side_truth


def test_error_is_the_rms_of_the_best_followed_inner_points_in_frontal_distances(turned):
    frontal = frontal_inter_ocular_distance(turned)
    errors = np.full(len(turned.landmarks), 50.0)  # jaw and MediaPipe's lip points far off: not read
    errors[INNER_FACE] = 0.03 * frontal
    errors[INNER_FACE[:10]] = 2.0 * frontal  # ten misplaced inner points: trimmed away
    assert landmark_error_percent(with_errors(turned, errors)) == pytest.approx(3.0, rel=1e-5)
    errors[INNER_FACE[0]] = np.nan  # a missing point is left out, not counted as a miss
    assert landmark_error_percent(with_errors(turned, errors)) == pytest.approx(3.0, rel=1e-5)
    assert round(FOLLOWED_SHARE * len(INNER_FACE)) == 41


def test_a_fit_that_misses_a_few_points_or_the_outline_is_accepted(turned):
    """What the bar before issue 47 refused: a small, turned face whose jaw, lip points and a few
    inner points (dlib's lower lip on a profile) are missed; the fit is right."""
    frontal = frontal_inter_ocular_distance(turned)
    errors = np.asarray(turned.landmark_errors_px, dtype=np.float64).copy()
    errors[JAW] += 0.3 * frontal
    errors[LIP_POINTS] += 0.15 * frontal
    errors[MOUTH[6:]] += 0.2 * frontal  # dlib's lower lip: 14 points
    errors[INNER_FACE[:30]] += 0.05 * frontal
    result = with_errors(turned, errors)
    assert result.landmark_rms_percent_iod > 6.0  # the old bar: RMS of all the points, % of the detected distance
    assert landmark_error_percent(result) < MAX_LANDMARK_ERROR_PERCENT
    check_fit(result, None)


def test_a_fit_that_misses_most_inner_points_is_refused(turned):
    frontal = frontal_inter_ocular_distance(turned)
    errors = np.asarray(turned.landmark_errors_px, dtype=np.float64).copy()
    errors[INNER_FACE[:15]] += 0.5 * frontal  # more than the ten that may be trimmed away
    with pytest.raises(NoFaceError, match="landmarks the face model can follow"):
        check_fit(with_errors(turned, errors), None)
    errors = np.full(len(errors), 1.01 * MAX_LANDMARK_ERROR_PERCENT * frontal / 100)  # just over the bar
    with pytest.raises(NoFaceError):
        check_fit(with_errors(turned, errors), None)
    check_fit(with_errors(turned, errors * 0.98), None)  # just under it


class _Given:
    name = "given"

    def __init__(self, found):
        self.found = found

    def detect(self, image, source="<array>"):
        return self.found


@pytest.mark.parametrize("quarter_turns", [1, 3])
def test_landmarks_found_on_a_face_lying_on_its_side_are_refused_with_a_reason(model, quarter_turns):
    """The hybrid detector without its rotation search, on the bundled photo turned by 90° or
    270°: the points it finds are no face the model can take (27–50 % of the face's size)."""
    image = np.ascontiguousarray(np.rot90(load_photo(asset_path("photos/astronaut.png")).image, quarter_turns))
    found = get_detector("hybrid")._detect(image, "turned.png")
    with pytest.raises(NoFaceError) as refused:
        fit(image, model, detector=_Given(found), photometric=False)
    message = str(refused.value)
    assert "\n" not in message
    assert message.startswith("<array>: landmarks: expected landmarks the face model can follow")
    assert "px between the eyes" in message and "upright" in message
    percent = float(message.split("found ")[1].split(" %")[0])
    assert percent > 2.5 * MAX_LANDMARK_ERROR_PERCENT


def test_the_fit_reports_what_the_bar_read(model):
    result = fit(asset_path("photos/astronaut.png"), model, photometric=False)
    report = result.info["landmark_check"]
    assert report["limit_percent"] == MAX_LANDMARK_ERROR_PERCENT
    assert report["error_percent"] == pytest.approx(landmark_error_percent(result), abs=1e-3)
    assert 1.0 < report["error_percent"] < 3.0  # the bundled photo: 1.8 %
