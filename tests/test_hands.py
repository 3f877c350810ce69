"""Hands: MediaPipe's palm detector and hand landmarks on the bundled photo with a shaded hand
composited over the cheek, the hand polygon mask, its place in the skin mask, and the failure
paths."""

import math

import numpy as np
import pytest

from facegeo.assets import asset_path
from facegeo.errors import InputError, ModelFileError
from facegeo.hands import FINGER_CHAINS, HAND_MARGIN, HEEL, Hand, HandDetector, default_hand_detector, hand_mask
from facegeo.photo import load_photo
from facegeo.skin_mask import skin_mask


def capsule(shape, a, b, r):
    """(H, W) float32 height of a lit cylinder with round ends from ``a`` to ``b`` (px), radius
    ``r``: sqrt(1 - (d / r)²) inside, 0 outside."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float32)
    a, b = np.float32(a), np.float32(b)
    ab = b - a
    t = np.clip(((xx - a[0]) * ab[0] + (yy - a[1]) * ab[1]) / float(ab @ ab), 0, 1)
    d = np.hypot(xx - a[0] - t * ab[0], yy - a[1] - t * ab[1])
    return np.sqrt(np.clip(1 - (d / r) ** 2, 0, 1))


def draw_hand(image, wrist, size, tone=(205, 150, 120)):
    """``image`` with a skin-coloured hand pointing up composited over it (palm, four fingers and
    a thumb as shaded cylinders, ``size`` px ≈ the palm length), and the (H, W) bool hand."""
    w = np.asarray(wrist, np.float64)
    P = lambda x, y: w + np.array([x, y]) * size  # noqa: E731
    parts = [(P(0, -0.15), P(0, -0.75), 0.42)]  # palm
    parts += [(P(x, -0.95), P(1.15 * x, -0.95 - L), 0.1) for x, L in zip((-0.3, -0.1, 0.1, 0.3), (0.75, 0.85, 0.8, 0.6))]
    parts.append((P(0.35, -0.35), P(0.75, -0.85), 0.12))  # thumb
    height = np.zeros(image.shape[:2], np.float32)
    for a, b, r in parts:
        h = capsule(image.shape[:2], a, b, r * size)
        height = np.where(h > 0, h, height)  # fingers over the palm
    hand = height > 0
    shade = (0.35 + 0.65 * height)[..., None]
    out = np.where(hand[..., None], np.float32(tone) * shade, image.astype(np.float32))
    return np.clip(np.round(out), 0, 255).astype(np.uint8), hand


@pytest.fixture(scope="module")
def photo():
    return load_photo(asset_path("photos/astronaut.png")).image


@pytest.fixture(scope="module")
def with_hand(photo):
    """The astronaut with a hand over her left cheek (image right), fingers up to the eye."""
    return draw_hand(photo, (260, 190), 50)


def iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


def test_hand_over_the_cheek_is_found_and_masked(photo, with_hand):
    image, hand = with_hand
    hands = default_hand_detector()(image)
    assert len(hands) == 1
    h = hands[0]
    assert h.landmarks.shape == (21, 3) and h.landmarks.dtype == np.float32 and h.presence > 0.8 and h.score > 0.5
    assert 25 < h.palm_length < 60  # the drawn palm: knuckles 0.95 × 50 px above the drawn wrist
    ys, xs = np.round(h.landmarks[[4, 8, 12, 16, 20], 1]).astype(int), np.round(h.landmarks[[4, 8, 12, 16, 20], 0]).astype(int)
    grown = np.pad(hand, 4)  # fingertips within 4 px of the drawn hand
    assert all(grown[y:y + 9, x:x + 9].any() for x, y in zip(xs, ys))
    mask = hand_mask(image.shape[:2], hands)
    assert mask[hand].mean() > 0.9
    assert mask.sum() < 2.0 * hand.sum()  # a margin, not a blanket
    assert default_hand_detector()(photo) == []  # no hand on the photo itself

    with_hands, without = skin_mask(image), skin_mask(image, hands=[])
    assert with_hands.hands == 1 and without.hands == 0 and with_hands.summary()["hands"] == 1
    assert with_hands.occlusion[hand].mean() > 0.97
    assert without.occlusion[hand].mean() < 0.5  # the colour model alone lets a skin-coloured hand through
    # the subject's right cheek (image left, beside the nose) stays skin: the hand's mask does not
    # spill onto it (the colour model's feathered specks reach 0.15 at single pixels there)
    cheek = with_hands.occlusion[115:130, 180:200]
    assert cheek.mean() < 0.01 and cheek.max() < 0.5


@pytest.mark.parametrize("turn", ["rot90", "rot180", "rot270", "flip"])
def test_hand_mask_follows_the_photo_turned_and_flipped(with_hand, turn):
    image, _ = with_hand
    forward = {"rot90": lambda a: np.rot90(a, 1), "rot180": lambda a: np.rot90(a, 2), "rot270": lambda a: np.rot90(a, 3),
               "flip": lambda a: a[:, ::-1]}[turn]
    reference = hand_mask(image.shape[:2], default_hand_detector()(image))
    turned = np.ascontiguousarray(forward(image))
    mask = hand_mask(turned.shape[:2], default_hand_detector()(turned))
    assert iou(mask, forward(reference)) > 0.8


def test_roi_from_palm_points_the_crop_at_the_fingers():
    box = np.array([100, 200, 140, 260], np.float32)  # 40 wide, 60 high, centre (120, 230)
    up = np.array([[120, 250], [0, 0], [120, 210]], np.float32)  # wrist below the middle knuckle
    centre, side, angle = HandDetector.roi_from_palm(box, up)
    assert angle == pytest.approx(0.0, abs=1e-9) and side == pytest.approx(2.6 * 60)
    np.testing.assert_allclose(centre, [120, 230 - 0.5 * 60])
    right = np.array([[100, 230], [0, 0], [140, 230]], np.float32)  # hand pointing to the image's right
    centre, side, angle = HandDetector.roi_from_palm(box, right)
    assert angle == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(centre, [120 + 0.5 * 60, 230], atol=1e-9)


def test_hand_mask_geometry():
    # a flat hand pointing up: wrist at (100, 150), knuckles 50 px above, fingers 40 px long
    lm = np.zeros((21, 3), np.float32)
    lm[0, :2] = (100, 150)
    for f, chain in enumerate(FINGER_CHAINS):
        x = 70 + 15 * f
        for k, i in enumerate(chain[1:]):
            lm[i, :2] = (x, 100 - 10 * k)
    lm[9, :2] = (100, 100)  # middle knuckle straight above the wrist: palm length 50
    hand = Hand(lm, 1.0, 1.0, np.zeros(4, np.float32))
    assert hand.palm_length == pytest.approx(50.0)
    mask = hand_mask((300, 200), [hand])
    r = HAND_MARGIN * 50
    heel_y = 150 + HEEL * 50
    assert mask[int(heel_y + r - 2), 100] and not mask[int(heel_y + r + 2), 100]  # below the heel
    assert mask[int(70 - r + 2), 100] and not mask[int(70 - r - 2), 100]  # above the middle fingertip
    assert mask[85, int(70 - r + 2)] and not mask[85, int(70 - r - 2)]  # beside the first finger
    assert not hand_mask((300, 200), []).any()
    assert hand_mask((300, 200), [hand], margin=0.0).sum() < mask.sum()


def test_missing_and_wrong_model_files_are_clear_errors(tmp_path):
    with pytest.raises(ModelFileError, match="no_palm.tflite"):
        HandDetector(palm_path=tmp_path / "no_palm.tflite").palm_model
    face = asset_path("mediapipe/face_detection_short_range.tflite")
    with pytest.raises(ModelFileError, match="input tensors"):
        HandDetector(palm_path=face).palm_model  # a face detector takes 128² input
    palm = asset_path("mediapipe/palm_detection_lite.tflite")
    with pytest.raises(ModelFileError, match="hand_landmark|input tensors"):
        HandDetector(landmark_path=palm).landmark_model  # the palm model has no 224² input
    junk = tmp_path / "junk.tflite"
    junk.write_bytes(b"not a flatbuffer")
    with pytest.raises(ModelFileError, match="junk.tflite"):
        HandDetector(palm_path=junk).palm_model


def test_bad_images_are_input_errors():
    detector = default_hand_detector()
    with pytest.raises(InputError, match="uint8"):
        detector(np.zeros((64, 64, 3), np.float32))
    with pytest.raises(InputError, match="uint8"):
        detector(np.zeros((64, 64), np.uint8))
    assert detector(np.full((64, 96, 3), 128, np.uint8)) == []  # a blank photo has no hand
