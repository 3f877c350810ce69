"""The default fitter, :func:`fit`: one photo -> landmarks (detected unless given) -> the MAP
landmark fit (:mod:`facegeo.fitting.landmark_fit`) -> albedo and SH lighting
(:mod:`facegeo.fitting.photometric`), checked (:mod:`facegeo.fitting.checks`)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from facegeo.camera import Camera
from facegeo.colour import srgb_to_linear
from facegeo.fitting.camera_estimate import camera_for_face
from facegeo.fitting.checks import check_fit
from facegeo.fitting.dense_term import DEFAULT_DENSE, DenseSettings, dense_surface_points, landmark_weights_with_dense
from facegeo.fitting.landmark_fit import solve_landmarks
from facegeo.fitting.photometric import fit_photometric
from facegeo.fitting.priors import DEFAULT_PRIORS, FitPriors
from facegeo.fitting.result import Fit
from facegeo.landmarks.dense import load_dense_correspondence
from facegeo.landmarks.detectors import FaceLandmarks, LandmarkDetector, get_detector
from facegeo.landmarks.scheme import LANDMARK_WEIGHTS, inter_ocular_distance
from facegeo.model_files import load_model
from facegeo.morphable_model import MorphableModel
from facegeo.photo import Photo, as_rgb_uint8, load_photo

if TYPE_CHECKING:
    from facegeo.fitting.shading_refine import ShadingSettings

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
    dense: DenseSettings | None = DEFAULT_DENSE,
    shading: ShadingSettings | None = None,
) -> Fit:
    """Fit the model to one photo: landmarks (detected unless given), pose, shape, expression,
    then albedo and SH lighting.

    Args:
        image: (H, W, 3) uint8 RGB array, a path, or a loaded :class:`Photo`.
        model: the morphable model (default: :func:`load_model`'s default).
        landmarks: optional (88, 2) pixel landmarks in the image's coordinates.
        detector: a detector name (``hybrid``, ``dlib``, ``mediapipe``) or instance.
        camera: intrinsics (default: :meth:`Camera.unknown_focal`); a camera whose focal is
            not known gets the one :func:`~facegeo.fitting.camera_estimate.camera_for_face`
            estimates from the face.
        photometric: run the albedo + lighting stage.
        init: start the landmark fit from this fit's pose, α and δ (e.g. a regressor's
            prediction) instead of solvePnP on the mean shape.
        priors: the landmark fit's priors (:class:`FitPriors`).
        dense: the dense term's settings (:mod:`facegeo.fitting.dense_term`): MediaPipe's 468
            face-mesh points on the model surface beside the 88, when the detector ran the face
            mesh and the model has a dense correspondence; None: the 88 points alone.
        shading: run the analysis-by-synthesis stage against the photo's shading with these
            settings (:mod:`facegeo.fitting.shading_refine`; implies the photometric stage);
            None (default): landmarks and the photometric stage only.
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
    camera = Camera.unknown_focal(width, height) if camera is None else camera
    detection: FaceLandmarks | None = None
    if landmarks is None:
        t0 = time.perf_counter()
        det = get_detector(detector) if isinstance(detector, str) else detector
        detection = det.detect(pixels, source)
        landmarks = detection.points
        notes.extend(detection.notes)
        timings["detect"] = time.perf_counter() - t0
    camera, camera_note = camera_for_face(camera, np.asarray(landmarks, dtype=np.float64), model)
    if camera_note:
        notes.append(camera_note)
    weights, surface = None, None
    if dense is not None and detection is not None and detection.dense is not None:
        correspondence = load_dense_correspondence(model)
        if correspondence is None:
            notes.append("no dense correspondence for this model: fitted to the 88 landmarks alone")
        else:
            surface = dense_surface_points(model, detection.dense, correspondence, inter_ocular_distance(landmarks), dense,
                                           detection.dense_spread)
            weights = landmark_weights_with_dense(LANDMARK_WEIGHTS, dense)
    solution = solve_landmarks(model, landmarks, camera, weights=weights, priors=priors, init=init, surface_points=surface)
    result = solution.fit
    result.timings = {**timings, **result.timings}
    if photometric or shading is not None:
        t0 = time.perf_counter()
        linear = srgb_to_linear(pixels.astype(np.float32) / 255.0)
        fit_photometric(model, result, linear)
        result.timings["photometric"] = time.perf_counter() - t0
        if shading is not None and "skipped" not in result.info.get("photometric", {}):
            from facegeo.fitting.shading_refine import refine_with_shading  # torch: only for this opt-in stage

            t0 = time.perf_counter()
            result.info["shading"] = refine_with_shading(model, result, solution.problem, solution.noise, linear,
                                                         solution.expression_scale, solution.expression_rate, shading)
            fit_photometric(model, result, linear)  # albedo and light for the refined shape
            result.timings["shading"] = time.perf_counter() - t0
    result.info.update(
        source=source,
        model=model.name,
        detector=detection.detector if detection else "given",
        face_box=detection.box.tolist() if detection else None,
        faces_found=detection.n_faces if detection else None,
        notes=notes + result.info.get("notes", []),  # the landmark fit's own (e.g. points left out)
    )
    check_fit(result, image)
    return result
