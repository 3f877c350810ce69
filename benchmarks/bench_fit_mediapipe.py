"""Real photos: the fitted depth profile against MediaPipe's own 3-D face mesh (an independent,
learned estimate), for the MAP fit, the fit before it and the mean shape.

    python benchmarks/bench_fit_mediapipe.py

For each photo of :func:`sample_photos.sample_photos`: MediaPipe's 468-point mesh (x, y in pixels,
z relative depth in the same scale, negative towards the camera) is taken at the 51 non-jaw iBUG
points (``MEDIAPIPE_TO_IBUG68[17:68]``; the jaw contour is a silhouette, not fixed points) and
lifted to camera space at the fitted face's depth (x, y back-projected, z scaled by depth / focal).
Each fitted face's landmark vertices (camera space, mm) are compared with it after the best
similarity transform: RMS distance (mm), RMS of the depth (z) component, and the depth of the
upper lip, lower lip and chin relative to the nose tip (mm, MediaPipe minus fit). Rows: the MAP
fit (the default), the fit before it (git, unbounded δ) and the mean shape posed by a pose-only
fit. The landmark RMS (px) and the expression weights outside [0, 1] are listed too.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fit_priors import BEFORE, previous_fit_landmarks  # noqa: E402
from fit_validation import DEPTH_POINTS  # noqa: E402
from test_fitting import similarity_align  # noqa: E402  (on the path via fit_validation)
from sample_photos import sample_photos  # noqa: E402

from facegeo import Camera, load_model, load_photo  # noqa: E402
from facegeo.fitting import LandmarkStage, fit_landmarks  # noqa: E402
from facegeo.landmarks import get_detector  # noqa: E402
from facegeo.landmarks.mediapipe_mesh import MEDIAPIPE_TO_IBUG68, MediaPipeFaceMesh  # noqa: E402
from facegeo.landmarks.scheme import INNER_FACE  # noqa: E402

POINTS = INNER_FACE


def mediapipe_camera_space(mesh: np.ndarray, camera: Camera, depth: float) -> np.ndarray:
    """(51, 3) mm: MediaPipe's points lifted to camera space at ``depth`` mm in front of it."""
    p = mesh[MEDIAPIPE_TO_IBUG68[POINTS]].astype(np.float64)
    x = (p[:, 0] + 0.5 - camera.cx) * depth / camera.focal  # mesh x, y use pixel-centre indices
    y = -(p[:, 1] + 0.5 - camera.cy) * depth / camera.focal
    z = -depth - p[:, 2] * depth / camera.focal
    return np.stack([x, y, z], axis=1)


def compare(model, fit, reference: np.ndarray) -> dict[str, float]:
    fitted = fit.vertices[model.landmark_indices[POINTS]].astype(np.float64)
    aligned = similarity_align(reference, fitted)
    out = {"rms": float(np.sqrt(((aligned - fitted) ** 2).sum(1).mean())),
           "rms_z": float(np.sqrt(((aligned[:, 2] - fitted[:, 2]) ** 2).mean()))}
    row = {int(p): i for i, p in enumerate(POINTS)}
    nose = row[30]
    for name, point in DEPTH_POINTS.items():
        if point in row:
            i = row[point]
            out[name] = float((aligned[i, 2] - aligned[nose, 2]) - (fitted[i, 2] - fitted[nose, 2]))
    return out


def main() -> None:
    model = load_model()
    before = previous_fit_landmarks()
    detector = get_detector("hybrid")
    mesher = MediaPipeFaceMesh()
    print("| photo | fit | landmark RMS px | δ outside [0, 1] | RMS to MediaPipe mm | depth RMS mm | upper lip mm | lower lip mm |\n|---|---|---|---|---|---|---|---|")
    for path in sample_photos():
        photo = load_photo(path)
        h, w = photo.image.shape[:2]
        camera = Camera.for_image(w, h)
        points = detector.detect(photo.image).points
        faces = mesher(photo.image)
        if not faces:
            print(f"| {path.name} | MediaPipe found no face | | | | | | |")
            continue
        fits = {
            "MAP (default)": fit_landmarks(model, points, camera),
            f"before ({BEFORE})": before(model, points, camera),
            "mean shape, pose only": fit_landmarks(model, points, camera, schedule=(LandmarkStage("pose", 8, 0, False),)),
        }
        depth = float(-fits["MAP (default)"].vertices[model.landmark_indices[30], 2])
        reference = mediapipe_camera_space(faces[0].mesh, camera, depth)
        for name, fit in fits.items():
            c = compare(model, fit, reference)
            out = int(((fit.delta < -1e-6) | (fit.delta > 1 + 1e-6)).sum())
            print(f"| {path.name} | {name} | {fit.landmark_rms_px:.2f} | {out} | {c['rms']:.2f} | {c['rms_z']:.2f} | "
                  f"{c['upper lip']:+.1f} | {c['lower lip']:+.1f} |", flush=True)


if __name__ == "__main__":
    main()
