"""The lids read by the iris model, the model's own lid gap, and the blink between them."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facegeo.assets import asset_path
from facegeo.camera import Camera
from facegeo.errors import InputError
from facegeo.landmarks import eyelids
from facegeo.photo import load_photo


def shut_left_eye(image: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """``image`` with the subject's left eye (iBUG 42-47) painted over with the skin around it and
    a lash line drawn through its middle: a shut eye."""
    centre = landmarks[42:48].mean(0)
    polygon = (centre + 1.3 * (landmarks[42:48] - centre)).astype(np.int32)
    mask = np.zeros(image.shape[:2], np.uint8)
    cv2.fillPoly(mask, [polygon], 255)
    out = cv2.inpaint(image, mask, 5, cv2.INPAINT_TELEA)
    middle = ((landmarks[42:46] + landmarks[[42, 47, 46, 45]]) / 2).astype(np.int32)
    cv2.polylines(out, [middle], False, (40, 30, 30), 2, cv2.LINE_AA)
    return out


@pytest.fixture(scope="module")
def photo():
    from facegeo.landmarks.detectors import detect_landmarks

    image = load_photo(asset_path("photos/astronaut.png")).image
    return image, detect_landmarks(image, "lids")


def test_open_eyes_read_open_and_the_mirror_swaps_them(photo):
    from facegeo.landmarks.detectors import detect_landmarks

    image, landmarks = photo
    gaps = eyelids.lid_gaps(image, landmarks)
    widths = np.linalg.norm(landmarks[[39, 45]] - landmarks[[36, 42]], axis=1)
    assert np.all((gaps / widths > 0.25) & (gaps / widths < 0.5))  # an open eye: a third of its width
    mirrored = np.ascontiguousarray(image[:, ::-1])
    swapped = eyelids.lid_gaps(mirrored, detect_landmarks(mirrored, "lids"))[::-1]
    assert np.allclose(swapped, gaps, rtol=0.1)


def test_a_shut_eye_reads_shut_and_the_other_stays_open(photo):
    image, landmarks = photo
    gaps = eyelids.lid_gaps(image, landmarks)
    shut = eyelids.lid_gaps(shut_left_eye(image, landmarks), landmarks)
    assert shut[1] < 0.6 * gaps[1] and abs(shut[0] - gaps[0]) < 0.05 * gaps[0]
    assert np.isnan(eyelids.lid_gaps(image, np.full((88, 2), np.nan))).all()


def test_blinks_between_the_open_gap_and_the_shut_share():
    frontal = np.eye(3)
    open_gaps = np.array([10.0, 8.0])
    assert np.allclose(eyelids.blinks(open_gaps, open_gaps, frontal), 0.0)
    shut = eyelids.SHUT_FRACTION * open_gaps
    assert np.allclose(eyelids.blinks(shut, open_gaps, frontal), 1.0)
    assert np.allclose(eyelids.blinks(0.5 * shut, open_gaps, frontal), 1.0)  # clipped
    assert np.allclose(eyelids.blinks(1.2 * open_gaps, open_gaps, frontal), 0.0)
    counted_open = (1.0 - eyelids.OPEN_NOISE) * open_gaps  # the reader's noise on an open eye: still open
    assert np.allclose(eyelids.blinks(counted_open, open_gaps, frontal), 0.0)
    assert np.allclose(eyelids.blinks(0.99 * counted_open, open_gaps, frontal), 0.0, atol=0.02)
    half = (counted_open + shut) / 2
    assert np.allclose(eyelids.blinks(half, open_gaps, frontal), 0.5)
    wink = np.array([open_gaps[0], shut[1]])
    assert np.allclose(eyelids.blinks(wink, open_gaps, frontal), [0.0, 1.0])
    # an eye without a reading takes the other's; none: NaN
    assert np.allclose(eyelids.blinks(np.array([np.nan, shut[1]]), open_gaps, frontal), 1.0)
    assert np.isnan(eyelids.blinks(np.full(2, np.nan), open_gaps, frontal)).all()


def test_the_far_eye_of_a_turned_head_takes_the_near_eyes_reading():
    open_gaps = np.array([10.0, 10.0])
    wink = np.array([10.0, eyelids.SHUT_FRACTION * 10.0])  # the left eye shut
    turn = np.radians(eyelids.EYE_OUTWARD_DEG)
    for yaw, expected in ((0.0, [0.0, 1.0]), (10.0, [0.0, 1.0])):
        rotation = Rotation.from_euler("y", yaw, degrees=True).as_matrix()
        assert np.allclose(eyelids.blinks(wink, open_gaps, rotation), expected)
    # turned so far that the left eye's outward direction is at acos(FACING[0]) from the camera: all the right's
    away = np.degrees(np.arccos(eyelids.FACING[0]) - turn)
    for sign in (1, -1):  # which way turns the left eye away: the one whose facing is lower
        rotation = Rotation.from_euler("y", sign * (away + 1.0), degrees=True).as_matrix()
        facing = (np.array([[-np.sin(turn), 0, np.cos(turn)], [np.sin(turn), 0, np.cos(turn)]]) @ rotation.T)[:, 2]
        read = eyelids.blinks(wink, open_gaps, rotation)
        far = int(np.argmin(facing))
        assert read[far] == pytest.approx(read[1 - far]) and read[1 - far] == pytest.approx([0.0, 1.0][1 - far])


def test_the_models_lid_gap_closes_with_its_blink_and_shrinks_with_distance(model):
    camera = Camera(1000.0, 320.0, 240.0, 640, 480)
    alpha, delta = np.zeros(model.n_id), np.zeros(model.n_exp)
    near = eyelids.model_lid_gaps(model, alpha, delta, np.eye(3), np.array([0.0, 0.0, -500.0]), camera)
    far = eyelids.model_lid_gaps(model, alpha, delta, np.eye(3), np.array([0.0, 0.0, -1000.0]), camera)
    assert np.all(near > 0) and np.allclose(far, near / 2, rtol=0.15)  # pinhole: about 1/depth
    names = list(model.expression_names)
    blink = delta.copy()
    blink[names.index("eyeBlink_L")] = 1.0
    shut = eyelids.model_lid_gaps(model, alpha, blink, np.eye(3), np.array([0.0, 0.0, -500.0]), camera)
    assert shut[1] < 0.2 * near[1] and shut[0] == pytest.approx(near[0], rel=1e-3)


def test_open_ratio_is_the_median_over_frames():
    gaps = np.array([[12.0, 9.0], [12.0, 9.0], [3.0, 2.0], [np.nan, 9.0]])  # a blink in frame 2, an eye unread
    model_gaps = np.full((4, 2), 10.0)
    assert np.allclose(eyelids.open_ratio(gaps, model_gaps), [1.2, 0.9])
    assert np.isnan(eyelids.open_ratio(np.full((2, 2), np.nan), model_gaps[:2])).all()


def test_a_measured_expression_is_held_at_its_value(model):
    from facegeo.fitting import DEFAULT_PRIORS, FitPriors
    from facegeo.fitting.landmark_fit import solve_landmarks
    from facegeo.landmarks.detectors import detect_landmarks

    image = load_photo(asset_path("photos/astronaut.png")).image
    landmarks = detect_landmarks(image, "lids")
    camera = Camera(1500.0, image.shape[1] / 2, image.shape[0] / 2, image.shape[1], image.shape[0])
    priors = dataclasses.replace(DEFAULT_PRIORS, measured_expressions=(("eyeBlink_L", 0.7), ("eyeBlink_R", 2.0), ("noSuchShape", 1.0)))
    fit = solve_landmarks(model, landmarks, camera, priors=priors).fit
    names = list(model.expression_names)
    assert fit.delta[names.index("eyeBlink_L")] == pytest.approx(0.7)
    assert fit.delta[names.index("eyeBlink_R")] == pytest.approx(model.expression_range[1][names.index("eyeBlink_R")])
    with pytest.raises(InputError, match="measured_expressions"):
        FitPriors(measured_expressions=(("eyeBlink_L", float("nan")),))
