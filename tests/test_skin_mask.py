"""The photo's skin mask: a synthetic face with known occluders, the robust colour model, and the
bundled photo through MediaPipe."""

import cv2
import numpy as np
import pytest

from facegeo.assets import asset_path
from facegeo.errors import NoFaceError
from facegeo.photo import load_photo
from facegeo.skin_mask import FaceRegions, _robust_gaussian, skin_mask, skin_mask_image


def ellipse(cx, cy, ax, ay, n=24):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([cx + ax * np.cos(t), cy + ay * np.sin(t)], 1).astype(np.float32)


@pytest.fixture(scope="module")
def synthetic():
    """A 256² 'face': skin-coloured oval with shading, dark hair on top, a blue collar at the
    bottom, a dark glasses rim around the left eye, red lips, dark brows."""
    H = W = 256
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    skin = np.array([205, 150, 125], np.float32)
    shade = np.clip(1.0 - 0.004 * np.abs(xx - 128), 0.4, 1.0)[..., None]  # darker towards the sides
    img = np.full((H, W, 3), [90, 110, 130], np.float32)
    face = ((xx - 128) / 80) ** 2 + ((yy - 130) / 105) ** 2 < 1
    img[face] = (skin * shade)[face]
    hair = face & (yy < 60)
    img[hair] = [60, 40, 25]
    collar = yy > 220
    img[collar] = [90, 120, 200]
    regions = FaceRegions(
        oval=ellipse(128, 130, 80, 105),
        eyes=(ellipse(98, 110, 14, 6), ellipse(158, 110, 14, 6)),
        brows=(ellipse(98, 92, 16, 4), ellipse(158, 92, 16, 4)),
        lips=ellipse(128, 185, 24, 9),
        mouth=ellipse(128, 185, 16, 2),
    )
    for polygons, colour in ((regions.eyes, (240, 240, 235)), (regions.brows, (70, 50, 35)), ([regions.lips], (190, 70, 80))):
        cv2.fillPoly(img, [np.round(p).astype(np.int32) for p in polygons], colour)  # painted where the regions say
    rim = np.abs(np.hypot((xx - 98) / 26, (yy - 112) / 16) - 1) < 0.12
    img[rim] = [20, 20, 22]
    rgb = np.clip(img, 0, 255).astype(np.uint8)
    return rgb, regions, dict(hair=hair, collar=collar, rim=rim, eyes=None)


def test_occluders_are_masked_and_skin_is_kept(synthetic):
    rgb, regions, parts = synthetic
    m = skin_mask(rgb, regions=regions)
    occ = m.occlusion
    assert occ.shape == rgb.shape[:2] and occ.dtype == np.float32 and 0 <= occ.min() and occ.max() <= 1
    assert occ[parts["hair"]].mean() > 0.95
    assert occ[parts["collar"] & (np.arange(256)[None, :] > 100) & (np.arange(256)[None, :] < 156)].mean() > 0.95
    assert occ[parts["rim"]].mean() > 0.9  # a dark frame on the face
    assert occ[108:113, 93:104].min() == 1.0  # eye interior
    assert occ[185, 125:132].min() == 1.0  # mouth opening
    cheeks = np.zeros_like(occ, bool)
    cheeks[140:165, 70:100] = cheeks[140:165, 160:190] = True
    assert occ[cheeks].max() < 0.05  # shaded skin is still skin
    lips = occ[176:179, 118:138]  # upper lip, 4+ px above the mouth opening (its edge is dilated and feathered)
    assert lips.mean() < 0.05 and lips.max() < 0.2  # red lips are a feature, kept (the mouth's feathered edge aside)
    assert occ[90:93, 92:104].mean() < 0.05  # dark brows are a feature, kept
    img = skin_mask_image(m)
    assert img.dtype == np.uint8 and img[150, 80] == 255 and img[30, 128] == 0


def test_robust_gaussian_ignores_a_third_of_outliers():
    rng = np.random.default_rng(0)
    cov = np.array([[0.01, 0.004], [0.004, 0.02]])
    good = rng.multivariate_normal([0.4, -0.3], cov, 4000)
    bad = rng.uniform(-2, 2, (2000, 2))
    mean, est = _robust_gaussian(np.concatenate([good, bad]))
    np.testing.assert_allclose(mean, [0.4, -0.3], atol=0.01)
    np.testing.assert_allclose(est, cov, rtol=0.25, atol=1e-3)


def test_no_face_and_no_landmarks_is_a_clear_error():
    with pytest.raises(NoFaceError, match="skin mask"):
        skin_mask(np.full((64, 64, 3), 128, np.uint8))


def test_bundled_photo_hair_and_suit_out_cheeks_in():
    photo = load_photo(asset_path("photos/astronaut.png"))
    m = skin_mask(photo.image)
    assert m.source == "mediapipe"
    from facegeo.landmarks.detectors import get_detector

    mesh = get_detector("mediapipe").mesh(photo.image)[0].mesh
    r = lambda i: tuple(np.round(mesh[i, :2]).astype(int))  # noqa: E731  (x, y) of mesh vertex i
    iod = np.linalg.norm(mesh[33, :2] - mesh[263, :2])
    for i in (50, 280, 4, 199):  # cheeks, nose tip, chin
        x, y = r(i)
        assert m.occlusion[y - 2:y + 3, x - 2:x + 3].max() < 0.1, i
    x, y = r(10)  # forehead top: hair 0.4 inter-ocular distances above it
    assert m.occlusion[int(y - 0.4 * iod), x] > 0.9
    x, y = r(152)  # the black suit collar below the chin
    assert m.occlusion[int(y + 0.6 * iod), x] > 0.9
    # fallback regions from iBUG points agree on the same pixels
    m68 = skin_mask(photo.image, regions=FaceRegions.from_ibug68(np.asarray(get_detector("mediapipe").detect(photo.image).points)))
    x, y = r(50)
    assert m68.occlusion[y, x] < 0.1
