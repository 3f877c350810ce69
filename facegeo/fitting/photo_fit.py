"""The default fitter, :func:`fit`: one photo -> landmarks (detected unless given) -> the MAP
landmark fit (:mod:`facegeo.fitting.landmark_fit`) -> albedo and SH lighting
(:mod:`facegeo.fitting.photometric`), checked (:mod:`facegeo.fitting.checks`)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from facegeo.camera import Camera
from facegeo.colour import srgb_to_linear
from facegeo.fitting.checks import check_fit
from facegeo.fitting.landmark_fit import fit_landmarks
from facegeo.fitting.photometric import fit_photometric
from facegeo.fitting.priors import DEFAULT_PRIORS, FitPriors
from facegeo.fitting.result import Fit
from facegeo.landmarks.detectors import FaceLandmarks, LandmarkDetector, get_detector
from facegeo.model_files import load_model
from facegeo.morphable_model import MorphableModel
from facegeo.photo import Photo, as_rgb_uint8, load_photo

__all__ = ["fit"]


def fit(
    image: np.ndarray | str | Path | Photo,
    model: MorphableModel | None = None,
    landmarks: np.ndarray | None = None,
    detector: str | LandmarkDetector = "hybrid",
    camera: Camera | None = None,
    photometric: bool = True,
    init: Fit | None = None,
    priors: FitPriors = DEFAULT_PRIORS,
) -> Fit:
    """Fit the model to one photo: landmarks (detected unless given), pose, shape, expression,
    then albedo and SH lighting.

    Args:
        image: (H, W, 3) uint8 RGB array, a path, or a loaded :class:`Photo`.
        model: the morphable model (default: :func:`load_model`'s default).
        landmarks: optional (88, 2) pixel landmarks in the image's coordinates.
        detector: a detector name (``hybrid``, ``dlib``, ``mediapipe``) or instance.
        camera: intrinsics (default: :meth:`Camera.for_image`, 40° field of view).
        photometric: run the albedo + lighting stage.
        init: start the landmark fit from this fit's pose, α and δ (e.g. a regressor's
            prediction) instead of solvePnP on the mean shape.
        priors: the landmark fit's priors (:class:`FitPriors`).
    """
    timings: dict[str, float] = {}
    notes: list[str] = []
    if isinstance(image, (str, Path)):
        t0 = time.perf_counter()
        image = load_photo(image)
        timings["load_image"] = time.perf_counter() - t0
    if isinstance(image, Photo):
        notes.extend(image.notes)
        source, pixels = image.path, image.image
    else:
        source, pixels = "<array>", as_rgb_uint8(image)
    t0 = time.perf_counter()
    model = load_model() if model is None else model
    timings["load_model"] = time.perf_counter() - t0
    height, width = pixels.shape[:2]
    camera = Camera.for_image(width, height) if camera is None else camera
    detection: FaceLandmarks | None = None
    if landmarks is None:
        t0 = time.perf_counter()
        det = get_detector(detector) if isinstance(detector, str) else detector
        detection = det.detect(pixels, source)
        landmarks = detection.points
        notes.extend(detection.notes)
        timings["detect"] = time.perf_counter() - t0
    result = fit_landmarks(model, landmarks, camera, priors=priors, init=init)
    result.timings = {**timings, **result.timings}
    if photometric:
        t0 = time.perf_counter()
        fit_photometric(model, result, srgb_to_linear(pixels.astype(np.float32) / 255.0))
        result.timings["photometric"] = time.perf_counter() - t0
    result.info.update(
        source=source,
        model=model.name,
        detector=detection.detector if detection else "given",
        face_box=detection.box.tolist() if detection else None,
        faces_found=detection.n_faces if detection else None,
        notes=notes,
    )
    check_fit(result, image)
    return result
