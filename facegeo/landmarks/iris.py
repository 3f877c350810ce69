"""Irises in a photo: MediaPipe's iris landmark model, and a robust iris colour for the eye material.

The model (``assets/mediapipe/iris_landmark.tflite``, from the mediapipe 0.10.14 wheel, run with
ai-edge-litert like :mod:`facegeo.landmarks.mediapipe_mesh`) takes one eye:

* input: (1, 64, 64, 3) float32 RGB in [0, 1], a square crop around the eye, rotated so that the
  eye corners lie on a horizontal line; the crop is centred on the corners' midpoint and its side
  is 2.3 × the larger of their horizontal and vertical distance (MediaPipe's
  ``IrisLandmarkLandmarksToRoi``). The model is trained on the eye on the image's left (the
  subject's right eye); the subject's left eye is mirrored horizontally first.
* outputs: ``output_iris`` (1, 15): 5 points (x, y, z) in crop pixels, the iris centre then 4
  points on its rim; ``output_eyes_contours_and_brows`` (1, 213): 71 eye-contour and brow points
  (the lids' rows, :data:`LOWER_LID` and :data:`UPPER_LID`, are read by :mod:`facegeo.landmarks.eyelids`).

Here the eye corners come from the fit's detected iBUG points (36/39: subject's right eye, 42/45:
left eye), so no second face-mesh pass is needed. Pixel coordinates as in :mod:`facegeo.camera`
(continuous, origin at the top-left image corner).

:func:`iris_colour` samples the ring between 45 % and 95 % of the iris radius (the pupil is
inside), only inside the eye opening (the polygon of iBUG 36–41 / 42–47, eroded by one pixel,
which keeps eyelids and lashes out), drops highlights (sRGB channel ≥ 0.92, or luminance more
than 2.5 robust σ above the median) and dark outliers (lashes, shadows: more than 2.5 robust σ
below), and returns the per-channel median in linear light, sRGB-encoded. It is not de-lit: it is
the colour the photo shows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from facegeo.colour import linear_to_srgb, srgb_to_linear
from facegeo.errors import ModelFileError
from facegeo.landmarks.scheme import LEFT_EYE, RIGHT_EYE

__all__ = ["IrisDetector", "Iris", "iris_colour", "sample_iris_ring", "IRIS_ASSET", "EYE_CORNERS", "LOWER_LID", "UPPER_LID"]

#: The bundled model, relative to ``facegeo.assets``.
IRIS_ASSET = "mediapipe/iris_landmark.tflite"
INPUT_SIZE = 64
#: ROI side / eye-corner distance (MediaPipe's IrisLandmarkLandmarksToRoi).
ROI_SCALE = 2.3
#: iBUG indices (start corner, end corner, eye polygon) and whether the crop is mirrored:
#: subject's right eye (image left) as the model expects, the left eye mirrored.
EYE_CORNERS = {"right": (36, 39, tuple(RIGHT_EYE), False), "left": (42, 45, tuple(LEFT_EYE), True)}
#: Rows of the eye-contour output on the lids, corner to corner (MediaPipe's eye contour: row 0
#: the eye's start corner, 8 its end corner; 1-7 the lower lid, 9-15 the upper lid from the
#: start corner's side), in the crop's orientation: for the mirrored left eye too.
LOWER_LID = tuple(range(0, 9))
UPPER_LID = (0, *range(9, 16), 8)
#: The ring sampled, as fractions of the iris radius.
RING = (0.45, 0.95)
#: Fewer valid pixels than this in both eyes together: no colour.
MIN_PIXELS = 10


@dataclass(frozen=True)
class Iris:
    """One iris: ``centre`` (2,) px, ``radius`` px (mean distance of the 4 rim points),
    ``rim`` (4, 2) px, and ``eye`` ("right" or "left", the subject's)."""

    eye: str
    centre: np.ndarray
    radius: float
    rim: np.ndarray


class IrisDetector:
    """MediaPipe's iris landmark model on the eyes of a photo (loaded on first use)."""

    def __init__(self, model_path: str | Path | None = None, num_threads: int | None = 1):
        self.model_path = None if model_path is None else Path(model_path)
        self.num_threads = num_threads
        self._model = None

    @property
    def model(self):
        if self._model is None:
            from facegeo.landmarks.mediapipe_mesh import _Model

            path = self.model_path
            if path is None:
                from facegeo.assets import asset_path

                try:
                    path = asset_path(IRIS_ASSET)
                except FileNotFoundError as exc:
                    raise ModelFileError(f"facegeo.assets/{IRIS_ASSET}", "file",
                                         "the bundled model (run assets/mediapipe/extract_mediapipe_models.py)",
                                         "missing") from exc
            self._model = _Model(path, (1, INPUT_SIZE, INPUT_SIZE, 3),
                                 {"contours": (1, 213), "iris": (1, 15)}, self.num_threads)
        return self._model

    def eyes(self, image: np.ndarray, landmarks: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
        """:meth:`eye_points` of each eye (``"right"``, ``"left"``: the subject's) of the face whose
        iBUG points (the first 68 rows of ``landmarks``, px) are given; an eye whose corners are
        not finite or less than 4 px apart is left out."""
        out = {}
        for eye, (a, b, _, mirror) in EYE_CORNERS.items():
            start, end = landmarks[a], landmarks[b]
            if not (np.all(np.isfinite(start)) and np.all(np.isfinite(end))) or np.linalg.norm(end - start) < 4.0:
                continue
            out[eye] = self.eye_points(image, start, end, mirror)
        return out

    def eye_points(self, image: np.ndarray, start: np.ndarray, end: np.ndarray,
                   mirror: bool) -> tuple[np.ndarray, np.ndarray, float]:
        """Both outputs for the eye whose corners are ``start``, ``end`` (px): the 5 iris points
        (5, 2) px, the 71 eye-contour and brow points (71, 2) px (:data:`LOWER_LID`,
        :data:`UPPER_LID`) and the ROI side in px."""
        start, end = np.asarray(start, np.float64), np.asarray(end, np.float64)
        centre = (start + end) / 2.0
        side = ROI_SCALE * float(np.max(np.abs(end - start)))
        angle = math.atan2(end[1] - start[1], end[0] - start[0])
        c, s = math.cos(angle), math.sin(angle)
        k = side / INPUT_SIZE
        sx = -k if mirror else k
        # crop pixel index (x, y) -> image pixel-centre coordinates (continuous minus 0.5)
        to_image = np.array([[sx * c, -k * s, 0.0], [sx * s, k * c, 0.0]])
        half = INPUT_SIZE / 2.0 - 0.5
        to_image[:, 2] = centre - 0.5 - to_image[:, :2] @ [half, half]
        source, to_source = image, np.eye(3)[:2]
        factor = int(k)
        if factor >= 2:  # box-filter big eyes down first so that the bilinear warp does not alias
            h, w = image.shape[:2]
            r = side * 0.75
            x0, y0 = int(max(centre[0] - r, 0)), int(max(centre[1] - r, 0))
            x1, y1 = int(min(centre[0] + r, w)), int(min(centre[1] + r, h))
            nx, ny = (x1 - x0) // factor, (y1 - y0) // factor
            if nx >= 1 and ny >= 1:
                source = cv2.resize(image[y0:y0 + ny * factor, x0:x0 + nx * factor], (nx, ny), interpolation=cv2.INTER_AREA)
                to_source = np.array([[1.0 / factor, 0.0, (0.5 - x0) / factor - 0.5],
                                      [0.0, 1.0 / factor, (0.5 - y0) / factor - 0.5]])
        sample = to_source[:, :2] @ to_image
        sample[:, 2] += to_source[:, 2]
        crop = cv2.warpAffine(source, sample, (INPUT_SIZE, INPUT_SIZE), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REPLICATE)
        out = self.model((crop.astype(np.float32) / 255.0)[None])

        def to_pixels(raw: np.ndarray) -> np.ndarray:  # continuous crop coordinates -> pixel index coordinates -> image
            return ((raw[:, :2].astype(np.float64) - 0.5) @ to_image[:, :2].T + to_image[:, 2] + 0.5).astype(np.float32)

        return to_pixels(out["iris"].reshape(5, 3)), to_pixels(out["contours"].reshape(71, 3)), side

    def __call__(self, image: np.ndarray, landmarks: np.ndarray) -> list[Iris]:
        """Both irises of the face whose iBUG points (the first 68 rows of ``landmarks``, px)
        are given; an eye whose corners are not finite or less than 4 px apart is skipped."""
        out = []
        for eye, (points, _, _) in self.eyes(image, landmarks).items():
            radius = float(np.linalg.norm(points[1:] - points[0], axis=1).mean())
            out.append(Iris(eye, points[0], radius, points[1:]))
        return out


def sample_iris_ring(image: np.ndarray, centre: np.ndarray, radius: float, eye_polygon: np.ndarray | None = None) -> np.ndarray:
    """Linear-RGB pixels (N, 3) float32 of the iris ring (:data:`RING` of ``radius`` around
    ``centre``, px), inside the eye polygon (eroded by one pixel) when given, without highlights
    and dark outliers (see the module docstring). ``image``: (H, W, 3) uint8 sRGB."""
    h, w = image.shape[:2]
    r_out = RING[1] * radius
    x0, x1 = max(int(centre[0] - r_out) - 1, 0), min(int(centre[0] + r_out) + 2, w)
    y0, y1 = max(int(centre[1] - r_out) - 1, 0), min(int(centre[1] + r_out) + 2, h)
    if x1 <= x0 or y1 <= y0:
        return np.zeros((0, 3), np.float32)
    ys, xs = np.mgrid[y0:y1, x0:x1]
    d = np.hypot(xs + 0.5 - centre[0], ys + 0.5 - centre[1])
    keep = (d >= RING[0] * radius) & (d <= r_out)
    if eye_polygon is not None:
        mask = np.zeros((h, w), np.uint8)
        cv2.fillPoly(mask, [np.round(np.asarray(eye_polygon) * 4 - 2).astype(np.int32)], 1, shift=2)
        mask = cv2.erode(mask, np.ones((3, 3), np.uint8))
        keep &= mask[y0:y1, x0:x1].astype(bool)
    srgb = image[y0:y1, x0:x1][keep].astype(np.float32) / 255.0
    srgb = srgb[srgb.max(axis=1) < 0.92]
    if len(srgb) == 0:
        return np.zeros((0, 3), np.float32)
    lin = srgb_to_linear(srgb)
    lum = lin @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    med = np.median(lum)
    sigma = 1.4826 * np.median(np.abs(lum - med)) + 1e-6
    return lin[np.abs(lum - med) <= 2.5 * sigma].astype(np.float32)


def iris_colour(image: np.ndarray, landmarks: np.ndarray, detector: IrisDetector | None = None
                ) -> tuple[tuple[float, float, float] | None, dict]:
    """The iris colour (sRGB triple in [0, 1]) of the face with these iBUG ``landmarks`` (px),
    and a JSON-ready report (irises found, pixels used). None with a ``note`` in the report when
    no eye gives an iris ring of at least :data:`MIN_PIXELS` valid pixels in all (eyes closed,
    too small, hidden)."""
    detector = detector or IrisDetector()
    landmarks = np.asarray(landmarks, np.float64)
    report: dict = {"irises": []}
    samples = []
    for iris in detector(image, landmarks):
        polygon = landmarks[list(EYE_CORNERS[iris.eye][2])]
        pixels = sample_iris_ring(image, iris.centre, iris.radius, polygon) if iris.radius >= 1.5 else np.zeros((0, 3))
        samples.append(pixels)
        report["irises"].append({"eye": iris.eye, "centre_px": [float(v) for v in iris.centre],
                                 "radius_px": round(iris.radius, 2), "pixels": int(len(pixels))})
    pixels = np.concatenate(samples) if samples else np.zeros((0, 3))
    if len(pixels) < MIN_PIXELS:
        report["note"] = f"iris colour not found ({len(pixels)} usable iris pixels, {MIN_PIXELS} needed): default colour used"
        return None, report
    srgb = linear_to_srgb(np.median(pixels, axis=0).astype(np.float32))
    colour = tuple(round(float(v), 4) for v in np.clip(srgb, 0.0, 1.0))
    report["srgb"] = list(colour)
    return colour, report
