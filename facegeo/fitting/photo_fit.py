"""The default fitter, :func:`fit`: one photo -> landmarks (detected unless given) -> the MAP
landmark fit (:mod:`facegeo.fitting.landmark_fit`) -> albedo and SH lighting
(:mod:`facegeo.fitting.photometric`), checked (:mod:`facegeo.fitting.checks`)."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from facegeo.camera import Camera
from facegeo.colour import srgb8_to_linear
from facegeo.fitting.camera_estimate import camera_for_face
from facegeo.fitting.checks import (FOLLOWED_SHARE, MAX_LANDMARK_ERROR_PERCENT, check_fit, frontal_inter_ocular_distance,
                                     landmark_error_percent)
from facegeo.fitting.dense_term import DEFAULT_DENSE, DenseSettings, dense_surface_points, landmark_weights_with_dense
from facegeo.fitting.landmark_fit import LandmarkSolution, landmark_targets, solve_landmarks
from facegeo.fitting.landmark_problem import SurfacePoints
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

__all__ = ["fit", "observe_photo", "finish_photo_fit", "PhotoObservation"]


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
    seen = observe_photo(image, model, landmarks, detector, camera, dense)
    solution = solve_landmarks(seen.model, seen.landmarks, seen.camera, weights=seen.weights, priors=priors, init=init,
                               surface_points=seen.surface_points)
    return finish_photo_fit(seen, solution, photometric, shading)


def finish_photo_fit(seen: PhotoObservation, solution: LandmarkSolution, photometric: bool = True,
                     shading: ShadingSettings | None = None) -> Fit:
    """The second half of :func:`fit`: the landmark ``solution`` of the photo ``seen``
    (:func:`observe_photo`) completed with albedo and SH lighting (``photometric``), the optional
    ``shading`` stage, the photo's notes and detection record, and checked
    (:func:`~facegeo.fitting.checks.check_fit`). Returns the completed fit (a new :class:`Fit`)."""
    model, pixels, detection = seen.model, seen.pixels, seen.detection
    result = replace(solution.fit, timings={**seen.timings, **solution.fit.timings})
    if photometric or shading is not None:
        t0 = time.perf_counter()
        linear = srgb8_to_linear(pixels)
        result = fit_photometric(model, result, linear)
        result.timings["photometric"] = time.perf_counter() - t0
        if shading is not None and "skipped" not in result.info.get("photometric", {}):
            from facegeo.fitting.shading_refine import refine_with_shading  # torch: only for this opt-in stage

            t0 = time.perf_counter()
            result, statistics = refine_with_shading(model, result, solution.problem, solution.noise, linear,
                                                     solution.expression_scale, solution.expression_rate, shading)
            result = fit_photometric(model, result, linear)  # albedo and light for the refined shape
            result.info["shading"] = statistics
            result.timings["shading"] = time.perf_counter() - t0
    result.info.update(
        source=seen.source,
        model=model.name,
        detector=detection.detector if detection else "given",
        face_box=detection.box.tolist() if detection else None,
        faces_found=detection.n_faces if detection else None,
        notes=seen.notes + result.info.get("notes", []),  # the landmark fit's own (e.g. points left out)
    )
    # what check_fit's landmark bar reads (facegeo.fitting.checks), reported with the fit
    result.info["landmark_check"] = {"error_percent": round(landmark_error_percent(result), 3),
                                     "limit_percent": MAX_LANDMARK_ERROR_PERCENT, "followed_share": FOLLOWED_SHARE,
                                     "frontal_iod_px": round(frontal_inter_ocular_distance(result), 2)}
    check_fit(result, seen.image)
    return result


@dataclass
class PhotoObservation:
    """What a fit observes in one photo (:func:`observe_photo`): ``image`` (the loaded
    :class:`Photo` or the array), ``source`` (its path or ``"<array>"``), ``pixels`` (H, W, 3)
    uint8 RGB, the ``model``, ``landmarks`` (88, 2) float px, the ``camera`` (its focal estimated
    when it was unknown), the ``detection`` (None for given landmarks), the landmark ``weights``
    (88,) and dense ``surface_points`` (None without the dense term), ``timings`` (s) and ``notes``."""

    image: np.ndarray | Photo
    source: str
    pixels: np.ndarray
    model: MorphableModel
    landmarks: np.ndarray
    camera: Camera
    detection: FaceLandmarks | None
    weights: np.ndarray | None
    surface_points: SurfacePoints | None
    timings: dict[str, float]
    notes: list[str]


def observe_photo(
    image: np.ndarray | str | Path | Photo,
    model: MorphableModel | None = None,
    landmarks: np.ndarray | None = None,
    detector: str | LandmarkDetector | FaceLandmarks = "hybrid",
    camera: Camera | None = None,
    dense: DenseSettings | None = DEFAULT_DENSE,
) -> PhotoObservation:
    """The first half of :func:`fit` (same arguments): the photo loaded, the landmarks detected
    (unless given), the camera's focal estimated when unknown and the dense surface points placed
    on the model; what a landmark fit of this photo needs, alone or beside other photos of the
    same person (:func:`facegeo.fitting.fit_photos`). Given landmarks of another shape than
    (88, 2) are an :class:`~facegeo.errors.InputError` before the photo is read. ``detector`` may
    also be a detection already made on this photo (a video's face followed from the frame
    before, :meth:`~facegeo.landmarks.detectors.HybridDetector.follow`)."""
    timings: dict[str, float] = {}
    notes: list[str] = []
    if landmarks is not None:
        landmarks = landmark_targets(landmarks)  # given ones checked before the photo is read
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
        if isinstance(detector, FaceLandmarks):  # detected already (a video's face followed from its previous frame)
            detection = detector
        else:
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
    return PhotoObservation(image, source, pixels, model, np.asarray(landmarks, dtype=np.float64), camera, detection, weights,
                            surface, timings, notes)
