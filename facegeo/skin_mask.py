"""Where a photo shows the face's own surface: a per-pixel mask that keeps hair, headwear,
glasses, clothing, eye interiors and teeth out of the texture.

The mask is built from what runs offline here, in four parts:

1. **Face regions** from MediaPipe's 468-point face mesh (:mod:`facegeo.landmarks.mediapipe_mesh`):
   the face oval, eyes (the lid contour: inside it is eyeball, never albedo), brows, lips and the
   mouth opening (inner lip contour: teeth, tongue). When MediaPipe finds no face, the same
   regions come from the 68 iBUG points of the fit (:meth:`FaceRegions.from_ibug68`).
2. **A skin-colour model fitted to this photo** on the skin that is reliably visible: the cheeks
   and nose between the lower eyelids and the upper lip, inside the face oval and away from the
   features. The colour feature is the log-chromaticity (log R/G, log B/G) of linear RGB, which is
   invariant to the shading's intensity. A robust Gaussian (trimmed re-estimation at the 97.5 %
   χ² quantile, three rounds) is fitted there; a pixel's sensor noise widens the Gaussian by
   (σ_noise / value)² per axis, so dark skin in shadow is not mistaken for an occluder, while black
   hair, glasses frames, collars and most headwear (chroma or brightness unlike the skin) are.
   Pixels darker than :data:`DARK_FRACTION` of the median skin luminance are not skin either.
3. **Structure**: lips and brows are facial features, kept whatever their colour; eye interiors
   and the mouth opening are always occluded, and so is everything outside the face oval (dilated
   by 10 % of the inter-ocular distance) above the upper eyelids: the temples and scalp, where
   hair and headwear are (blond hair has skin's chroma). Thin dark structures (glasses frames,
   strands) are pixels darker than :data:`LOCAL_DARK` of their neighbourhood. Colour-occluded specks thinner than ~3 % of the
   inter-ocular distance (pores, freckles) are dropped by a morphological opening, the rest is
   dilated by :data:`HALO_FRACTION` of the inter-ocular distance (the soft fringe of hair strands
   and frames) and feathered.

4. **Hands**: a hand in front of the face is skin-coloured, so the colour model lets it through;
   MediaPipe's palm detector and hand landmark model find it by shape instead, and its polygon
   (:func:`facegeo.hands.hand_mask`) is occluded like the rest.
5. **Background**: MediaPipe's selfie segmentation (:mod:`facegeo.person_segmentation`) says
   where the person is; further than 0.3 inter-ocular distances outside the face oval, pixels it
   gives less than 0.5 are background (walls, flags, skies, car interiors: of the skin's colour
   or not). Nearer the face the mesh and the colour model decide (on a partly covered face the
   segmentation can cut into the cheek). In a greyscale photo (the sampled skin passes
   :func:`facegeo.colour.is_greyscale`: no chroma for the colour model) nothing further than 0.1
   inter-ocular distances outside the face oval is skin (a glove, a coat or a collar of the skin's
   grey: the cameraman's), and at the oval's rim pixels brighter than :data:`BRIGHT_FRACTION` ×
   the skin's median luminance are not skin either (white collars, grey hair; in a colour photo
   the lit side of a face under a hard light can be). In a colour photo, below the eyes and
   outside the face oval, pixels as bright and less saturated than :data:`WHITE_SATURATION` × the
   skin's chroma are not skin: a white collar beside darker skin, or beside a small face whose
   blurred, compressed pixels widen the colour model (a face 21 px between the eyes in a
   640 × 480 clip: the skin's chroma σ 0.3, the collar's at 2.4 σ).
6. **Glasses**: frames are thin structures darker than the skin on both sides, whatever their
   colour (tortoiseshell passes the colour model): in the band of the eyes (from the brows to
   the cheekbones, across the whole face) a morphological black-hat of the log-luminance (the
   closing with a disc of :data:`FRAME_WIDTH` × the inter-ocular distance, minus the image)
   deeper than :data:`FRAME_DEPTH` marks them.
7. **Holes on clear skin**: colour-occluded blobs that lie wholly inside the face oval, away
   from the eyes, brows, lips and frames, and smaller than :data:`MAX_HOLE` × the inter-ocular
   distance squared (shadowed wrinkles, a highlight, a blemish whose chroma strays) are skin.
8. **Padding**: a crop padded out at the image's sides by repeating its last row or column
   (:func:`padded_border`) shows nothing of the face there: where the face
   (its oval dilated by 0.3 inter-ocular distances) reaches it, it is occluded, with the halo over
   its join (a repeated line of the cheek is skin to every test above, and would be drawn into the
   texture as streaks; a flat band of the photo's own, a wall or a sky, can look the same, and
   away from the face it is left to the tests above).

It also measures the photo's **white references**: the sclera (the brightest half of each eye's
interior, its glints aside; of an eye whose colour disagrees with the other's, which has lid
skin in it, none) and, where the mouth is open, the teeth; their mean linear RGB
(:attr:`SkinMask.white_reference`) is evidence of the light's colour for the texture stage.

:func:`skin_mask` returns a :class:`SkinMask`; its ``occlusion`` (1 = something other than the
face's surface is seen) is what :func:`facegeo.uv.unwrap` folds into M_vis; ``facegeo unwrap``
and ``facegeo reconstruct`` save it as ``skin_mask.png`` (:func:`skin_mask_image`: 255 = the face's
own surface, 0 = occluded).

The model's regions live here too (the one face-regions module), measured on the mean shape from
its 68 landmark vertices (model space, mm, +Y up, +Z out of the face), so any topology with
landmarks gets them: :func:`skin_vertex_mask` (the vertices the photometric fits trust) and
:func:`vertex_regions` (the soft region masks of the texture stage's material priors).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from facegeo.colour import is_greyscale, luminance, srgb8_to_linear
from facegeo.errors import NoFaceError
from facegeo.hands import Hand, default_hand_detector, hand_mask
from facegeo.landmarks import scheme as ibug
from facegeo.person_segmentation import default_person_segmenter
from facegeo.photo import as_rgb_uint8
from facegeo.robust_gaussian import robust_gaussian

if TYPE_CHECKING:
    from facegeo.morphable_model import MorphableModel

__all__ = ["SkinMask", "FaceRegions", "skin_mask", "skin_mask_image", "padded_border", "PAD_TOLERANCE", "PAD_MIN_LINES", "PAD_TEXTURE", "white_reference", "DARK_FRACTION", "HALO_FRACTION",
           "LOCAL_DARK", "FRAME_WIDTH", "FRAME_DEPTH", "MAX_HOLE", "EYES_AGREE", "skin_vertex_mask", "vertex_regions", "REGION_NAMES",
           "RAMP_MM"]

# MediaPipe face-mesh contours (vertex indices of the 468-point canonical mesh, in order).
FACE_OVAL = [10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377, 152, 148,
             176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109]
RIGHT_EYE = [33, 7, 163, 144, 145, 153, 154, 155, 133, 173, 157, 158, 159, 160, 161, 246]
LEFT_EYE = [263, 249, 390, 373, 374, 380, 381, 382, 362, 398, 384, 385, 386, 387, 388, 466]
RIGHT_BROW = [70, 63, 105, 66, 107, 55, 65, 52, 53, 46]
LEFT_BROW = [300, 293, 334, 296, 336, 285, 295, 282, 283, 276]
LIPS_OUTER = [61, 146, 91, 181, 84, 17, 314, 405, 321, 375, 291, 409, 270, 269, 267, 0, 37, 39, 40, 185]
LIPS_INNER = [78, 95, 88, 178, 87, 14, 317, 402, 318, 324, 308, 415, 310, 311, 312, 13, 82, 81, 80, 191]

#: Pixels darker than this fraction of the sampled skin's median luminance are not skin.
DARK_FRACTION = 0.2
#: Occlusion is dilated by this fraction of the inter-ocular distance (hair strands, frame edges).
HALO_FRACTION = 0.04
#: Mahalanobis distances (σ) of the skin-colour model: skin below the first, occluder above the second.
SKIN_SIGMAS = (2.5, 4.0)
#: A pixel darker than this fraction of its neighbourhood's mean luminance (Gaussian, σ = 12 % of the
#: inter-ocular distance) is a thin occluder (frame, strand).
LOCAL_DARK = 0.15
#: Sensor noise in linear RGB assumed when widening the colour model for dark pixels.
NOISE_LINEAR = 0.006
#: Radius of the black-hat's disc (fraction of the inter-ocular distance): frames up to twice as
#: wide are found (the thick rims of 1950s glasses are ~0.08 inter-ocular distances).
FRAME_WIDTH = 0.07
#: Black-hat depth in log-luminance above which a thin structure in the eyes' band is a frame
#: (0.35: 30 % darker than the skin on both sides; lid creases and wrinkles are shallower).
FRAME_DEPTH = 0.35
#: Colour-occluded blobs inside the face oval smaller than this × the inter-ocular distance²
#: are skin (holes closed).
MAX_HOLE = 0.15
#: The two eyes' sclera chroma (log R/G, log B/G) differ by at most this under one light; beyond
#: it the more saturated one has lid skin in it (on a turned face one eye's lid polygon takes in
#: skin) and only the other is a white reference. bench_albedo_scans' renders: 0.03–0.11 facing
#: the camera, 0.16–0.38 at ±40°, where the warmer eye was the nearer one, its polygon on lid skin.
EYES_AGREE = 0.15
#: Person probability below which a pixel outside the face oval is background.
PERSON_THRESHOLD = 0.5
#: A line (row or column) at the image's side is padding where 99 % of its pixels are within this
#: many 8-bit levels (every channel) of the side's outermost line, and so are all lines between.
PAD_TOLERANCE = 2
#: Padding is a band of at least this many such lines (one repeated line can be a photo's own).
PAD_MIN_LINES = 2
#: A repeated line is padding only where at least this share of its neighbouring pixels differ by
#: more than :data:`PAD_TOLERANCE` (the cropped photos' lines across a face: 0.25–0.65).
PAD_TEXTURE = 0.1
#: In a greyscale photo, pixels at the face oval's rim (within 0.1 inter-ocular distances either
#: side) brighter than this × the sampled skin's median luminance are not skin (white collars,
#: grey hair: its colour model lets them through).
BRIGHT_FRACTION = 2.5
#: In a colour photo, such pixels are not skin where their chroma's length (log R/G, log B/G) is
#: below this × the sampled skin's.
WHITE_SATURATION = 0.5


@dataclass
class FaceRegions:
    """Face-feature polygons in pixels (pixel-centre convention: the top-left pixel's centre is
    (0, 0)), each an (n, 2) float32 array."""

    oval: np.ndarray
    eyes: tuple[np.ndarray, np.ndarray]
    brows: tuple[np.ndarray, np.ndarray]
    lips: np.ndarray
    mouth: np.ndarray

    @classmethod
    def from_mesh468(cls, mesh: np.ndarray) -> FaceRegions:
        """From MediaPipe's (468, 2|3) mesh in pixels (pixel-centre convention)."""
        p = np.asarray(mesh, np.float32)[:, :2]
        return cls(p[FACE_OVAL], (p[RIGHT_EYE], p[LEFT_EYE]), (p[RIGHT_BROW], p[LEFT_BROW]), p[LIPS_OUTER], p[LIPS_INNER])

    @classmethod
    def from_ibug68(cls, points: np.ndarray) -> FaceRegions:
        """From 68 (or the hybrid 88) iBUG points in pixels, corner-origin convention (the fit's
        ``landmarks``). The oval's upper half is the brows raised by 60 % of the brow-to-chin
        height (no forehead points exist)."""
        p = np.asarray(points, np.float32)[ibug.IBUG68] - 0.5
        up = 0.6 * (p[ibug.CHIN, 1] - p[ibug.BROWS, 1].mean())
        forehead = p[ibug.BROWS[::-1]] - np.array([0.0, up], np.float32)
        brow_band = lambda b: np.concatenate([b - [0.0, 0.04 * up], b[::-1] + [0.0, 0.04 * up]])  # noqa: E731
        return cls(np.concatenate([p[ibug.JAW], forehead]), (p[ibug.RIGHT_EYE], p[ibug.LEFT_EYE]),
                   (brow_band(p[ibug.RIGHT_BROW]), brow_band(p[ibug.LEFT_BROW])), p[ibug.OUTER_LIP], p[ibug.INNER_LIP])

    @property
    def interocular(self) -> float:
        """Distance between the eye centres in pixels."""
        return float(np.linalg.norm(self.eyes[0].mean(0) - self.eyes[1].mean(0)))


@dataclass
class SkinMask:
    """The mask of one photo, all (H, W) float32 in [0, 1] except where stated.

    occlusion: 1 where the pixel shows something other than the face's own surface (hair,
        glasses, clothing, eye interiors, the mouth opening); what :func:`facegeo.uv.unwrap`'s
        ``occlusion`` takes.
    skin_probability: the colour model's verdict before the structural rules (1 = skin colour).
    sample: bool, the pixels the colour model was fitted on.
    mean, covariance: (2,) and (2, 2) float64, the robust Gaussian of (log R/G, log B/G).
    source: ``"mediapipe"`` or ``"ibug68"`` (where the regions came from).
    hands: the number of hands masked out.
    white_reference: (3,) float64 mean linear RGB of the sclera (and teeth) pixels, or None
        where too few were seen (:func:`white_reference`).
    white_pixels: how many pixels it averages.
    frames: pixels taken for glasses frames; holes_closed: pixels of skin given back.
    """

    occlusion: np.ndarray
    skin_probability: np.ndarray
    sample: np.ndarray
    mean: np.ndarray
    covariance: np.ndarray
    source: str
    hands: int = 0
    white_reference: np.ndarray | None = None
    white_pixels: int = 0
    frames: int = 0
    holes_closed: int = 0

    def summary(self) -> dict[str, float | str]:
        """JSON-ready statistics (for reports)."""
        return {"source": self.source, "occluded_fraction": float(self.occlusion.mean()),
                "sample_pixels": int(self.sample.sum()), "hands": self.hands, "chroma_mean": self.mean.tolist(),
                "chroma_sigma": np.sqrt(np.diag(self.covariance)).tolist(),
                "white_reference": None if self.white_reference is None else [float(v) for v in self.white_reference],
                "white_pixels": self.white_pixels, "frame_pixels": self.frames, "holes_closed_pixels": self.holes_closed}


def _fill(shape: tuple[int, int], polygons, value: float = 1.0) -> np.ndarray:
    out = np.zeros(shape, np.uint8)
    for poly in polygons:
        cv2.fillPoly(out, [np.round(np.asarray(poly) * 16).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
    return out.astype(bool)


def _disc(radius: float) -> np.ndarray:
    r = max(1, int(round(radius)))
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


def _chroma(linear: np.ndarray) -> np.ndarray:
    """(..., 3) linear RGB -> (..., 2) float64 log-chromaticity (log R/G, log B/G)."""
    x = np.maximum(linear.astype(np.float64), 1e-3)
    return np.stack([np.log(x[..., 0] / x[..., 1]), np.log(x[..., 2] / x[..., 1])], axis=-1)


def white_reference(linear: np.ndarray, regions: FaceRegions) -> tuple[np.ndarray | None, int]:
    """Mean linear RGB (3,) float64 of the photo's white references and their pixel count: in
    each eye's interior (the lid polygon shrunk by 15 % towards its centre: no lashes), the
    brighter half of the pixels below the 97th percentile (the sclera; the iris and pupil are the
    darker half, the glints the top), and of those the less saturated half (on a turned face the
    polygon takes in lid skin); where the two eyes' chromas differ by more than
    :data:`EYES_AGREE`, only the less saturated eye's; in the mouth opening, when it is open (its
    height over 15 % of the inter-ocular distance), the pixels brighter than twice the opening's
    median (teeth).
    None where fewer than 12 pixels qualify. ``linear`` (H, W, 3) linear RGB."""
    H, W = linear.shape[:2]
    lum = luminance(linear)
    eyes = []
    for eye in regions.eyes:
        centre = eye.mean(0)
        inner = _fill((H, W), [centre + 0.85 * (eye - centre)])
        values = lum[inner]
        if values.size < 8:
            continue
        lo, hi = np.percentile(values, [50, 97])
        bright = linear[inner & (lum >= lo) & (lum <= hi)]
        c = _chroma(bright)
        saturation = np.hypot(c[:, 0], c[:, 1])
        eyes.append(bright[saturation <= np.median(saturation)])  # the whiter half: lids and skin stay out
    picked = [e for e in eyes if len(e)]
    if len(picked) == 2:  # one light, two scleras: where they disagree, lid skin came into one (it is warmer)
        means = [_chroma(e.astype(np.float64).mean(axis=0)) for e in picked]
        if float(np.linalg.norm(means[0] - means[1])) > EYES_AGREE:
            picked = [picked[int(np.argmin([np.hypot(*m) for m in means]))]]
    mouth = regions.mouth
    if float(mouth[:, 1].max() - mouth[:, 1].min()) > 0.15 * regions.interocular:
        inside = _fill((H, W), [mouth])
        if inside.sum() >= 8:
            picked.append(linear[inside & (lum > 2.0 * np.median(lum[inside]))])
    pixels = np.concatenate(picked) if picked else np.zeros((0, 3))
    if len(pixels) < 12:
        return None, int(len(pixels))
    return pixels.astype(np.float64).mean(axis=0), int(len(pixels))


def padded_border(rgb: np.ndarray) -> np.ndarray:
    """(H, W) bool: the bands at the sides of the (H, W, 3) uint8 photo that are a crop's padding
    by repetition of its last row or column, at least :data:`PAD_MIN_LINES` lines wide (lines
    equal to the side's outermost within :data:`PAD_TOLERANCE`; the last of them is the photo's
    own), where that line is textured (:data:`PAD_TEXTURE`). A textured line repeated is what
    draws streaks into the texture (the cheek's last column, skin to every colour test); a flat
    one repeated draws none, and is as likely a flat band of the photo's own (a wall, a sky, a
    collar of one colour), as is a constant padding, whose join the texture stage's fringe tests
    take (:mod:`facegeo.texturing.default.occluders`)."""
    H, W = rgb.shape[:2]
    padding = np.zeros((H, W), bool)
    image = rgb.astype(np.int16)
    for flip, axis in ((False, 1), (True, 1), (False, 0), (True, 0)):  # left, right, top, bottom
        lines = np.moveaxis(image, axis, 0)  # (lines, pixels, 3) from this side inwards
        lines = lines[::-1] if flip else lines
        outer = lines[0]
        if float((np.abs(np.diff(outer, axis=0)).max(axis=-1) > PAD_TOLERANCE).mean()) < PAD_TEXTURE:
            continue
        run = 0
        for line in lines[: len(lines) // 2]:
            if np.quantile(np.abs(line - outer).max(axis=-1), 0.99) > PAD_TOLERANCE:
                break
            run += 1
        band = run - 1  # the last line of the run is the photo's own
        if band >= PAD_MIN_LINES:
            n = H if axis == 0 else W
            span = slice(n - band, n) if flip else slice(0, band)
            padding[(span, slice(None)) if axis == 0 else (slice(None), span)] = True
    return padding


def _glasses_frames(lum: np.ndarray, regions: FaceRegions, oval: np.ndarray, iod: float, skin_lum: float) -> np.ndarray:
    """(H, W) bool: thin dark structures in the eyes' band (module docstring, part 6). The
    log-luminance is taken above a floor of 10 % of the skin's median luminance (``skin_lum``) so
    that the noise of dark pixels makes no structure; a structure is a frame when its connected
    piece is long (over 0.3 inter-ocular distances) and thin (it fills under 35 % of its
    bounding box: a rim, a bridge, an arm, not a patch of wrinkles or hair)."""
    H, W = lum.shape
    log_l = np.log(lum + np.float32(0.1 * skin_lum)).astype(np.float32)
    blackhat = cv2.morphologyEx(log_l, cv2.MORPH_CLOSE, _disc(FRAME_WIDTH * iod)) - log_l
    top = min(float(b[:, 1].min()) for b in regions.brows) - 0.1 * iod
    bottom = max(float(e[:, 1].max()) for e in regions.eyes) + 0.45 * iod
    rows = np.arange(H, dtype=np.float32)[:, None]
    band = (rows > top) & (rows < bottom) & cv2.dilate(oval.astype(np.uint8), _disc(0.3 * iod)).astype(bool)
    frames = (blackhat > FRAME_DEPTH) & band
    n, labels, stats, _ = cv2.connectedComponentsWithStats(frames.astype(np.uint8), connectivity=8)
    w, h, area = stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT], stats[:, cv2.CC_STAT_AREA]
    keep = (np.maximum(w, h) > 0.3 * iod) & (area < 0.35 * w * h)
    keep[0] = False
    return keep[labels]


def _close_holes(occluded: np.ndarray, oval: np.ndarray, keep_out: np.ndarray, iod: float) -> np.ndarray:
    """(H, W) bool: the colour-occluded blobs of ``occluded`` that are holes in clear skin
    (module docstring, part 7): inside the oval eroded by 0.05 iod, not touching ``keep_out``
    (features, frames), smaller than MAX_HOLE · iod²."""
    inner = cv2.erode(oval.astype(np.uint8), _disc(0.05 * iod)).astype(bool)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(occluded.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros_like(occluded)
    outside = np.bincount(labels[occluded & (~inner | keep_out)], minlength=n) > 0
    hole = ~outside & (stats[:, cv2.CC_STAT_AREA] < MAX_HOLE * iod * iod)
    hole[0] = False
    return hole[labels]


def skin_mask(image: np.ndarray, landmarks: np.ndarray | None = None, *, regions: FaceRegions | None = None,
              hands: list[Hand] | None = None, person: np.ndarray | None = None, source: str = "<array>") -> SkinMask:
    """The skin mask of an (H, W, 3) uint8 RGB photo (see the module docstring).

    Args:
        image: the photo (any input :func:`facegeo.photo.as_rgb_uint8` accepts).
        landmarks: optional (68 or 88, 2) iBUG points (corner-origin pixels, e.g. a fit's
            ``landmarks``), used when MediaPipe finds no face.
        regions: face regions already known (skips MediaPipe's face mesh).
        hands: the hands already found (default: :func:`facegeo.hands.default_hand_detector` runs).
        person: (H, W) person probability already computed (default:
            :func:`facegeo.person_segmentation.default_person_segmenter` runs).
        source: the photo's name for error messages.
    Raises:
        NoFaceError: MediaPipe finds no face and no ``landmarks`` were given.
    """
    rgb = as_rgb_uint8(image, source)
    origin = "given"
    if regions is None:
        from facegeo.landmarks.detectors import get_detector

        faces = get_detector("mediapipe").mesh(rgb)
        if faces:
            regions, origin = FaceRegions.from_mesh468(faces[0].mesh), "mediapipe"
        elif landmarks is not None:
            regions, origin = FaceRegions.from_ibug68(landmarks), "ibug68"
        else:
            raise NoFaceError(source, "face", "a face for the skin mask (MediaPipe found none)")
    H, W = rgb.shape[:2]
    iod = max(regions.interocular, 4.0)
    linear = srgb8_to_linear(rgb)
    lum = luminance(linear)

    oval = _fill((H, W), [regions.oval])
    eyes = _fill((H, W), regions.eyes)
    mouth = _fill((H, W), [regions.mouth])
    lips = _fill((H, W), [regions.lips]) & ~mouth
    brows = _fill((H, W), regions.brows)
    features = cv2.dilate((eyes | brows | lips | mouth).astype(np.uint8), _disc(0.12 * iod)).astype(bool)
    # reliably visible skin: cheeks and nose between the lower lids and the upper lip
    eye_bottom = max(float(e[:, 1].max()) for e in regions.eyes) + 0.1 * iod
    lip_top = float(regions.lips[:, 1].min()) - 0.05 * iod
    rows = np.arange(H, dtype=np.float32)[:, None]
    sample = oval & ~features & (rows > eye_bottom) & (rows < lip_top) & (lum > 1e-3)
    if sample.sum() < 50:  # tiny or odd faces: the whole oval minus the features
        sample = oval & ~features
    if sample.sum() < 10:
        raise NoFaceError(source, "skin", "at least 10 visible skin pixels inside the face", f"{int(sample.sum())}")

    chroma = _chroma(linear)
    mean, cov = robust_gaussian(chroma[sample])
    # per-pixel Mahalanobis distance with the sensor noise of dark pixels added to the covariance
    g = np.maximum(linear[..., 1].astype(np.float64), 1e-3)
    noise_rg = (NOISE_LINEAR / np.maximum(linear[..., 0], 1e-3)) ** 2 + (NOISE_LINEAR / g) ** 2
    noise_bg = (NOISE_LINEAR / np.maximum(linear[..., 2], 1e-3)) ** 2 + (NOISE_LINEAR / g) ** 2
    d = chroma - mean
    a, b, c = cov[0, 0] + noise_rg, cov[0, 1], cov[1, 1] + noise_bg
    det = np.maximum(a * c - b * b, 1e-12)
    d2 = (c * d[..., 0] ** 2 - 2 * b * d[..., 0] * d[..., 1] + a * d[..., 1] ** 2) / det
    lo, hi = SKIN_SIGMAS
    prob = np.clip((hi - np.sqrt(d2)) / (hi - lo), 0.0, 1.0)
    skin_lum = float(np.median(lum[sample]))
    prob *= np.clip((lum / max(skin_lum, 1e-4) - DARK_FRACTION * 0.5) / (DARK_FRACTION * 0.5), 0.0, 1.0)
    prob = prob.astype(np.float32)

    # outside the face oval and above the eyes is where hair and headwear are: occluded outright
    eye_top = min(float(e[:, 1].min()) for e in regions.eyes)
    near_oval = cv2.dilate(oval.astype(np.uint8), _disc(0.1 * iod)).astype(bool)
    by_colour = cv2.morphologyEx(((prob < 0.5) & ~(lips | brows)).astype(np.uint8), cv2.MORPH_OPEN,
                                 _disc(0.015 * iod)).astype(bool)
    frames = _glasses_frames(lum, regions, oval, iod, skin_lum) & ~(eyes | mouth | brows)
    holes = _close_holes(by_colour, oval, features | cv2.dilate(frames.astype(np.uint8), _disc(0.05 * iod)).astype(bool), iod)
    occluded = (by_colour & ~holes) | (~near_oval & (rows < eye_top) & ~(lips | brows)) | frames
    # thin dark structures on the face (strands of hair, dark frames): much darker than their
    # neighbourhood, where skin creases and shadows are only somewhat darker
    local = cv2.GaussianBlur(lum, (0, 0), 0.12 * iod)
    occluded |= (lum < LOCAL_DARK * local) & ~(lips | brows | eyes)
    if hands is None:
        hands = default_hand_detector()(rgb)
    occluded |= hand_mask((H, W), hands)
    if person is None:
        person = default_person_segmenter()(rgb)
    inner_oval = cv2.erode(oval.astype(np.uint8), _disc(0.1 * iod)).astype(bool)
    # the segmentation is trusted away from the face only (on a partly covered face it can cut
    # into the cheek); near the face the colour model and the mesh decide
    near_face = cv2.dilate(oval.astype(np.uint8), _disc(0.3 * iod)).astype(bool)
    occluded |= (np.asarray(person, np.float32) < PERSON_THRESHOLD) & ~near_face
    if is_greyscale(rgb[sample].astype(np.float32) / 255.0):  # no chroma: the colour model cannot tell a white
        # collar, a black glove or a grey coat from skin; only the face oval's own surface is kept
        occluded |= ((lum > BRIGHT_FRACTION * skin_lum) & ~inner_oval) | (~near_oval & ~(lips | brows))
    else:  # a white collar beside darker skin, or where a small face's blurred pixels widen the colour
        # model: below the eyes and outside the face oval, as bright and less than half as saturated
        # is not skin (inside the oval, hard light's lit side is as bright and, near clipping, as pale)
        pale = (lum > BRIGHT_FRACTION * skin_lum) & ~oval & (rows > eye_top)
        pale[pale] = np.hypot(*chroma[pale].T) < WHITE_SATURATION * float(np.hypot(*mean))
        occluded |= pale
    padding = padded_border(rgb)
    if (padding & near_face).any():  # a crop's padding that the face reaches: no photo there (its join
        # mixes in too: the halo)
        occluded |= padding
    occluded = cv2.dilate(occluded.astype(np.uint8), _disc(HALO_FRACTION * iod)).astype(bool)
    occluded |= cv2.dilate((eyes | mouth).astype(np.uint8), _disc(0.02 * iod)).astype(bool)  # lashes, lip edge
    occluded = occluded.astype(np.float32)
    sigma = max(0.5, 0.02 * iod)
    occlusion = np.clip(cv2.GaussianBlur(occluded, (0, 0), sigma) * 1.5, 0.0, 1.0)  # feathered, 1 on the occluder
    occlusion = np.maximum(occlusion, (eyes | mouth).astype(np.float32))
    white, n_white = white_reference(linear, regions)
    return SkinMask(occlusion.astype(np.float32), prob, sample, mean, cov, origin, len(hands), white, n_white,
                    int(frames.sum()), int(holes.sum()))


def skin_mask_image(mask: SkinMask) -> np.ndarray:
    """(H, W) uint8 picture of the mask as saved (``skin_mask.png``): 255 where the photo shows
    the face's own surface, 0 where an occluder (or an eye interior, the mouth opening) covers it."""
    return np.clip(np.round((1.0 - mask.occlusion) * 255.0), 0, 255).astype(np.uint8)


# ------------------------------------------------------------------------- the model's regions
#: The soft regions of :func:`vertex_regions`.
REGION_NAMES = ("forehead", "nose", "cheeks", "chin", "lips", "brows", "eyes")
#: Width (mm) of the linear ramp from 1 to 0 at each region's border.
RAMP_MM = 4.0


def skin_vertex_mask(model: MorphableModel) -> np.ndarray:
    """(V,) bool: the model's face region minus eyes (14 mm around iBUG 36–47), brows (9 mm
    around 17–26) and lips (8 mm around 48–67), measured on the mean shape."""
    mean = model.mean_shape
    keep = model.face_mask.copy()
    x, y, z = (np.ascontiguousarray(c) for c in mean.T)
    for points, radius in ((ibug.EYES, 14.0), (ibug.BROWS, 9.0), (ibug.MOUTH, 8.0)):
        centres = mean[model.landmark_indices[points]]
        dx, dy, dz = x[:, None] - centres[:, 0], y[:, None] - centres[:, 1], z[:, None] - centres[:, 2]
        # (V, K) squared distances, the bits of summing the squared (V, K, 3) differences over
        # the last axis, in a tenth of the time that reduction of length 3 takes
        keep &= ((dx * dx + dy * dy) + dz * dz).min(axis=1) > radius * radius
    return keep


def _near(points: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
    d = np.sqrt(((points[:, None, :] - centres[None]) ** 2).sum(-1)).min(axis=1)
    return np.clip((radius + RAMP_MM - d) / RAMP_MM, 0.0, 1.0)


def _ramp(signed_mm: np.ndarray) -> np.ndarray:
    """1 where ``signed_mm`` ≥ RAMP_MM, 0 where ≤ 0."""
    return np.clip(signed_mm / RAMP_MM, 0.0, 1.0)


def _inside_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(N,) bool: which of the (N, 2) points lie inside the (K, 2) polygon or on its edges
    (OpenCV's test, on the points within the polygon's bounding box)."""
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    candidates = np.flatnonzero(np.all((points >= lo) & (points <= hi), axis=1))
    contour = polygon.astype(np.float32)
    inside = np.zeros(len(points), bool)
    inside[candidates] = [cv2.pointPolygonTest(contour, (float(x), float(y)), False) >= 0 for x, y in points[candidates]]
    return inside


def vertex_regions(model: MorphableModel) -> dict[str, np.ndarray]:
    """name -> (V,) float32 soft mask in [0, 1] for :data:`REGION_NAMES`, on the face region; each
    mask ramps linearly from 1 to 0 over :data:`RAMP_MM` at its border. Every rule is one line."""
    p = model.mean_shape.astype(np.float64)
    lm = p[model.landmark_indices[ibug.IBUG68]]
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    face = model.face_mask.astype(np.float64)
    front = _ramp(z - (lm[ibug.JAW_ENDS, 2].mean() - 5.0))  # in front of the jaw's top: the face, not the head sides
    nose_half = 0.5 * abs(lm[ibug.NOSTRILS[-1], 0] - lm[ibug.NOSTRILS[0], 0]) + 4.0  # nostril wings plus a margin
    eye_x = np.abs(lm[ibug.OUTER_EYE_CORNERS, 0]).max()  # outer eye corners
    brow_top = lm[ibug.BROWS, 1].max()

    eyes = _near(p, lm[ibug.EYES], 7.0)  # lids and canthi: within 7 mm of the eye contour
    brows = _near(p, lm[ibug.BROWS], 6.0) * (1 - eyes)  # hair of the brows: 6 mm around their landmarks
    inside_lips = _inside_polygon(p[:, :2], lm[ibug.OUTER_LIP, :2]) & (z > lm[ibug.OUTER_LIP, 2].min() - 10.0)
    lips = np.maximum(inside_lips.astype(np.float64), _near(p, lm[ibug.OUTER_LIP], 1.0))  # the vermilion
    nose = _near(p, lm[ibug.NOSE], 9.0) * _ramp(nose_half - np.abs(x) + RAMP_MM)  # bridge, tip, wings
    forehead = _ramp(y - brow_top + 2.0) * _ramp(eye_x + 8.0 - np.abs(x)) * front  # above the brows (brows win)
    cheeks = (
        _ramp(lm[40, 1] - 6.0 - y)  # below the lower lids
        * _ramp(y - (lm[57, 1] - 2.0))  # above the lower lip line
        * _ramp(np.abs(x) - nose_half - 3.0)  # beside the nose
        * front
    )
    chin = _ramp(lm[57, 1] - 4.0 - y) * _ramp(24.0 - np.abs(x)) * front  # below the lower lip, central
    masks = {"forehead": forehead, "nose": nose, "cheeks": cheeks, "chin": chin, "lips": lips, "brows": brows, "eyes": eyes}
    # features win over the broad skin regions they lie in
    features = np.maximum.reduce([lips, brows, eyes])
    for name in ("forehead", "nose", "cheeks", "chin"):
        masks[name] = masks[name] * (1 - features)
    return {name: (m * face).astype(np.float32) for name, m in masks.items()}
