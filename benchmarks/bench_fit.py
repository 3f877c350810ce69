"""Fit benchmark: error against iterations and time (synthetic), and the real-photo timings.

    python benchmarks/bench_fit.py [--instances 20] [--plot benchmarks/out/fit_error_vs_iterations.png]

Synthetic: noiseless faces of the bundled model with realistic expression mixes
(:func:`fit_validation.make_faces`, ``kind="model"``: α ~ N(0, I), δ in [0, 1], yaw ±50°) projected
into a 512×512 camera, without and with 1 px landmark noise; ``fit_landmarks`` with the fine stage
cut to k Levenberg–Marquardt iterations. Reported: reprojection RMS (px), the 3D error of the
face region after similarity alignment as a fraction of the mean shape's, and the time per fit
as a ratio to the default schedule measured in the same run. Real photo: model load,
detection (cold and warm) and the fit stages on the bundled photo.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

from facegeo import fit, fit_landmarks, load_model, load_photo
from facegeo.assets import asset_path
from facegeo.fitting import LANDMARK_SCHEDULE, LandmarkStage
from facegeo.landmarks import get_detector
from facegeo.landmarks.scheme import inter_ocular_distance

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_fitting import similarity_rms  # noqa: E402  (one definition of the 3D error)
sys.path.insert(0, str(Path(__file__).resolve().parent))
from fit_validation import CAMERA, make_faces  # noqa: E402


def synthetic_table(model, instances: int, noise_px: float) -> list[tuple]:
    rng = np.random.default_rng(2024)
    cases = []
    for face in make_faces(model, instances, seed=2024, kind="model"):
        lm = face.landmarks
        cases.append((face.shape, lm + rng.normal(0, noise_px, lm.shape) if noise_px else lm))
    camera = CAMERA
    face = model.face_mask
    rows = []
    default_fine = LANDMARK_SCHEDULE[-1].iterations
    for fine in sorted({0, 2, 4, 8, 12, default_fine, 40}):
        schedule = LANDMARK_SCHEDULE[:-1] + (LandmarkStage("fine", fine, None, True),)
        rms, ratio, seconds = [], [], []
        for shape, lm in cases:
            t0 = time.perf_counter()
            f = fit_landmarks(model, lm, camera, schedule=schedule)
            seconds.append(time.perf_counter() - t0)
            rms.append(f.landmark_rms_px)
            ratio.append(similarity_rms(f.shape_vertices[face], shape[face]) / similarity_rms(model.mean_shape[face], shape[face]))
        total = sum(s.iterations for s in schedule[:-1]) + fine
        rows.append((fine, total, float(np.median(rms)), float(np.max(rms)), float(np.mean(ratio)), float(np.max(ratio)), float(np.mean(seconds))))
    reference = next(r[6] for r in rows if r[0] == default_fine)
    print(f"\nsynthetic, {instances} instances, landmark noise {noise_px} px (time ratio: against the default schedule, this run)")
    print("| fine iters | total iters | RMS median px | RMS max px | 3D err / mean-shape err (mean) | (max) | ms per fit | time ratio |")
    print("|---|---|---|---|---|---|---|---|")
    for fine, total, med, mx, rmean, rmax, sec in rows:
        print(f"| {fine} | {total} | {med:.3f} | {mx:.3f} | {rmean:.3f} | {rmax:.3f} | {1000 * sec:.1f} | {sec / reference:.2f} |")
    return rows


def real_photo(model) -> None:
    photo_path = asset_path("photos/astronaut.png")
    t0 = time.perf_counter()
    fresh = load_model(asset_path("ict_facekit/ict_face_model.npz"))  # an explicit path skips the cache
    t_model = time.perf_counter() - t0
    photo = load_photo(photo_path)
    detector = get_detector("hybrid")
    t0 = time.perf_counter()
    detection = detector.detect(photo.image)
    t_cold = time.perf_counter() - t0
    warm = []
    for _ in range(5):
        t0 = time.perf_counter()
        detector.detect(photo.image)
        warm.append(time.perf_counter() - t0)
    fits = [fit(photo, fresh, landmarks=detection.points) for _ in range(5)]
    iod = inter_ocular_distance(detection.points)
    lm = np.median([f.timings["landmarks"] for f in fits])
    ph = np.median([f.timings["photometric"] for f in fits])
    print(f"\nreal photo {photo_path.name} ({photo.image.shape[1]}x{photo.image.shape[0]}), hybrid landmarks, 2-core CPU")
    print("| stage | seconds |")
    print("|---|---|")
    print(f"| load model (npz, cold) | {t_model:.3f} |")
    print(f"| detect, first call (loads dlib + LiteRT models) | {t_cold:.3f} |")
    print(f"| detect, warm (median of 5) | {np.median(warm):.3f} |")
    print(f"| fit: pose + landmark LM (median of 5) | {lm:.3f} |")
    print(f"| fit: photometric albedo + SH (median of 5) | {ph:.3f} |")
    print(f"| fit total (ratio to detection warm: {(lm + ph) / np.median(warm):.2f}) | {lm + ph:.3f} |")
    print(f"landmark RMS {fits[0].landmark_rms_px:.2f} px = {100 * fits[0].landmark_rms_px / iod:.2f} % of the inter-ocular distance ({iod:.1f} px)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--instances", type=int, default=20)
    parser.add_argument("--plot", type=Path, default=Path("benchmarks/out/fit_error_vs_iterations.png"))
    args = parser.parse_args()
    torch.set_num_threads(2)
    model = load_model()
    clean = synthetic_table(model, args.instances, 0.0)
    noisy = synthetic_table(model, args.instances, 1.0)
    real_photo(model)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for rows, label in ((clean, "noiseless"), (noisy, "1 px noise")):
        totals = [r[1] for r in rows]
        axes[0].plot(totals, [r[2] for r in rows], "o-", label=f"reprojection RMS, {label}")
        axes[1].plot([1000 * r[6] for r in rows], [r[4] for r in rows], "o-", label=label)
    axes[0].set(xlabel="Levenberg–Marquardt iterations", ylabel="median RMS (px)", yscale="log")
    axes[1].set(xlabel="ms per fit", ylabel="3D error / mean-shape error")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend()
    args.plot.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(args.plot, dpi=110)
    print(f"\nplot: {args.plot}")


if __name__ == "__main__":
    main()
