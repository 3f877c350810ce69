"""The photo's skin mask: a synthetic face with known occluders, the robust colour model, and the
bundled photo through MediaPipe."""

import cv2
import numpy as np
import pytest

from facegeo.assets import asset_path
from facegeo.errors import NoFaceError
from facegeo.photo import load_photo
from facegeo.skin_mask import FaceRegions, skin_mask, skin_mask_image, white_reference


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


def test_white_reference_is_the_sclera_not_the_iris():
    """A synthetic eye: a dark iris disc in a bright, slightly warm sclera; the reference is the
    sclera's colour, and None where the eyes are too small to hold 12 pixels."""
    H = W = 128
    linear = np.full((H, W, 3), 0.2, np.float32)
    eye = ellipse(64, 64, 30, 12)
    cv2.fillPoly(linear, [np.round(eye).astype(np.int32)], (0.8, 0.7, 0.6))
    cv2.circle(linear, (64, 64), 9, (0.05, 0.03, 0.02), -1)
    regions = FaceRegions(oval=ellipse(64, 64, 60, 60), eyes=(eye, eye + [0.0, 0.0]), brows=(eye, eye),
                          lips=ellipse(64, 110, 10, 4), mouth=ellipse(64, 110, 6, 1))
    ref, n = white_reference(linear, regions)
    assert n >= 12
    np.testing.assert_allclose(ref, [0.8, 0.7, 0.6], atol=0.02)
    tiny = FaceRegions(oval=regions.oval, eyes=(ellipse(64, 64, 1.5, 0.8, 8),) * 2, brows=regions.brows, lips=regions.lips,
                       mouth=regions.mouth)
    assert white_reference(linear, tiny)[0] is None


def test_white_reference_leaves_out_an_eye_full_of_lid_skin():
    """Two eyes under one light: the left one's interior is sclera (0.8, 0.7, 0.6), the right one's
    mostly lid skin (0.6, 0.35, 0.25: a turned face's nearer eye). Their chromas differ by far more
    than EYES_AGREE, so the reference is the left eye's sclera alone; two clean eyes are averaged."""
    H, W = 128, 256
    linear = np.full((H, W, 3), 0.2, np.float32)
    left, right = ellipse(64, 64, 30, 12), ellipse(192, 64, 30, 12)
    cv2.fillPoly(linear, [np.round(left).astype(np.int32)], (0.8, 0.7, 0.6))
    cv2.fillPoly(linear, [np.round(right).astype(np.int32)], (0.6, 0.35, 0.25))
    regions = FaceRegions(oval=ellipse(128, 64, 120, 60), eyes=(left, right), brows=(left, right),
                          lips=ellipse(128, 110, 10, 4), mouth=ellipse(128, 110, 6, 1))
    ref, _ = white_reference(linear, regions)
    np.testing.assert_allclose(ref, [0.8, 0.7, 0.6], atol=0.02)
    cv2.fillPoly(linear, [np.round(right).astype(np.int32)], (0.78, 0.7, 0.62))  # both sclera: within EYES_AGREE
    ref, _ = white_reference(linear, regions)
    np.testing.assert_allclose(ref, [0.79, 0.7, 0.61], atol=0.02)


def test_tortoiseshell_frames_and_background_are_masked(synthetic):
    """Frames of the skin's own chroma (darker) pass the colour model but are thin and dark: the
    frame detector takes them; a skin-coloured background beside the head is taken by the person
    segmentation (given here), while a small stray-chroma blob on the cheek is a hole closed."""
    rgb, regions, parts = synthetic
    img = rgb.astype(np.float32)
    yy, xx = np.mgrid[0:256, 0:256].astype(np.float32)
    rim = np.abs(np.hypot((xx - 158) / 26, (yy - 112) / 16) - 1) < 0.1
    img[rim] = [95, 62, 45]  # brown, skin's chroma, ~55 % darker
    background = (xx < 30) & (yy > 150) & (yy < 210)
    img[background] = [205, 150, 125]  # skin-coloured wall
    blob = np.hypot(xx - 85, yy - 152) < 4
    img[blob] = [150, 150, 60]  # a stray-chroma spot on clear skin
    person = np.ones((256, 256), np.float32)
    person[:, :40] = 0.0
    m = skin_mask(np.clip(img, 0, 255).astype(np.uint8), regions=regions, person=person, hands=[])
    assert m.occlusion[rim].mean() > 0.9 and m.frames > 0
    assert m.occlusion[background].mean() > 0.95
    assert m.occlusion[blob].max() < 0.1 and m.holes_closed > 0
    without = skin_mask(np.clip(img, 0, 255).astype(np.uint8), regions=regions, person=np.ones((256, 256), np.float32), hands=[])
    assert without.occlusion[background].mean() < 0.5  # the colour model alone lets most of the wall through


def test_greyscale_photo_keeps_only_the_face_oval(synthetic):
    """Without chroma a glove or a coat of the skin's grey cannot be told from skin: in a greyscale
    photo only the face oval (and its near rim) is kept, its shaded cheeks included."""
    rgb, regions, _ = synthetic
    grey = rgb.astype(np.float32) @ np.float32([0.299, 0.587, 0.114])
    yy, xx = np.mgrid[0:256, 0:256]
    glove = (yy >= 243) & (xx > 106) & (xx < 150)  # below the chin: within 0.3, beyond 0.1 IOD of the oval
    grey[glove] = grey[150, 128]  # the cheek's own grey
    image = np.repeat(np.clip(grey, 0, 255).astype(np.uint8)[..., None], 3, axis=-1)
    person = np.ones((256, 256), np.float32)
    m = skin_mask(image, regions=regions, person=person, hands=[])
    assert m.occlusion[glove].min() > 0.95
    assert m.occlusion[140:165, 70:100].max() < 0.05 and m.occlusion[140:165, 160:190].max() < 0.05
    colour = rgb.copy()
    colour[glove] = rgb[150, 128]  # in colour the same patch is skin-coloured: the colour model keeps it (the collar's halo aside)
    assert skin_mask(colour, regions=regions, person=person, hands=[]).occlusion[249:, 116:140].max() < 0.05


def test_a_white_collar_below_a_dark_face_is_masked_where_the_colour_model_keeps_it(synthetic):
    """A dark face whose pixels' chroma is as spread as a small, compressed face's (the colour
    model then keeps a warm white): a white collar below the chin, outside the oval, ~9× as bright
    as the skin and a fifth as saturated, is masked; the face's own lit skin (2.2× as bright, its
    chroma kept) and the shaded cheeks stay skin."""
    _, regions, _ = synthetic
    H = W = 256
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    rng = np.random.default_rng(5)
    img = np.full((H, W, 3), [60, 70, 90], np.float32)
    face = ((xx - 128) / 80) ** 2 + ((yy - 130) / 105) ** 2 < 1
    jitter = np.exp(rng.normal(0.0, 0.3, (H, W, 2))).astype(np.float32)  # chroma spread: R and B against G
    skin = np.stack([115 * jitter[..., 0], np.full((H, W), 70, np.float32), 50 * jitter[..., 1]], axis=-1)
    img[face] = skin[face]
    lit = face & ((xx - 165) ** 2 + (yy - 150) ** 2 < 12 ** 2)  # the lit side of a cheek: bright, its own chroma
    img[lit] = skin[lit] * 2.2
    collar = (yy >= 240) & (xx > 106) & (xx < 150)  # below the chin: outside the oval, within 0.3 IOD of it
    img[collar] = [235, 222, 200]
    rgb = np.clip(img, 0, 255).astype(np.uint8)
    m = skin_mask(rgb, regions=regions, person=np.ones((H, W), np.float32), hands=[])
    assert m.skin_probability[collar].mean() > 0.5  # the colour model alone takes it for skin
    assert m.occlusion[collar].min() > 0.95
    assert m.occlusion[lit & ((xx - 165) ** 2 + (yy - 150) ** 2 < 8 ** 2)].max() < 0.05
    assert m.occlusion[140:165, 70:100].max() < 0.05


def test_person_segmentation_finds_the_bundled_photos_subject():
    from facegeo.person_segmentation import default_person_segmenter

    photo = load_photo(asset_path("photos/astronaut.png"))
    person = default_person_segmenter()(photo.image)
    from facegeo.landmarks.detectors import get_detector

    H, W = person.shape
    assert person.shape == photo.image.shape[:2] and person.dtype == np.float32
    x, y = np.round(get_detector("mediapipe").mesh(photo.image)[0].mesh[4, :2]).astype(int)  # the nose tip
    assert person[y, x] > 0.9
    assert person[H // 8, int(0.97 * W)] < 0.1  # the wall at the top right
