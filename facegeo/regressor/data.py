"""Training data: face crops around landmarks, their crop cameras, augmentation, the landmark
cache and the train/validation split.

A crop is the square of side ``crop_scale`` × the larger side of the landmarks' bounding box,
centred on it, resampled to S × S. Resampling only scales and shifts, so the crop's camera is the
photo's camera with focal·s and principal point (c − corner)·s: a pose predicted in the crop is the
pose in the photo. Pixel coordinates are corner-origin (:mod:`facegeo.camera`).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from facegeo.camera import Camera
from facegeo.errors import FacegeoError, InputError
from facegeo.landmarks.scheme import HYBRID_MIRROR, N_LANDMARKS
from facegeo.photo import load_photo

__all__ = ["IMAGE_SUFFIXES", "Sample", "crop_box", "crop_face", "FaceCrops", "list_images", "landmark_table",
           "split_names", "TRUTH_FILE"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".webp", ".tif", ".tiff")
#: ``make-synthetic-faces`` writes its ground truth (parameters, landmarks, cameras) here.
TRUTH_FILE = "faces.npz"


def crop_box(landmarks: np.ndarray, crop_scale: float) -> tuple[float, float, float]:
    """(x0, y0, side) px of the square crop around the finite rows of (88, 2) ``landmarks``."""
    p = landmarks[np.isfinite(landmarks).all(axis=1)]
    if len(p) < 2:
        raise InputError("<landmarks>", "landmarks", "at least 2 finite points for the face crop", str(len(p)))
    lo, hi = p.min(0), p.max(0)
    side = float(crop_scale * max(hi - lo))
    centre = (lo + hi) / 2
    return float(centre[0] - side / 2), float(centre[1] - side / 2), max(side, 8.0)


def crop_face(image: np.ndarray, box: tuple[float, float, float], size: int) -> np.ndarray:
    """The (size, size, 3) uint8 crop of ``box`` = (x0, y0, side) from an (H, W, 3) uint8 image:
    area-averaged when shrinking, bilinear otherwise; outside the photo edge pixels repeat."""
    x0, y0, side = box
    s = size / side
    if s < 1.0:  # shrink the whole photo first with area averaging (no aliasing), then shift
        h, w = image.shape[:2]
        nw, nh = max(1, round(w * s)), max(1, round(h * s))
        image = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_AREA)
        sx, sy = nw / w, nh / h
    else:
        sx = sy = 1.0
    # corner-origin x' = s·x - s·x0 maps to OpenCV's centre-origin grid as x'_i = a·x_i + b
    ax, ay = s / sx, s / sy
    m = np.array([[ax, 0.0, ax * 0.5 - s * x0 - 0.5], [0.0, ay, ay * 0.5 - s * y0 - 0.5]])
    return cv2.warpAffine(image, m, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


@dataclass(frozen=True)
class Sample:
    """One training image: its path, (88, 2) float32 landmarks in the loaded photo's pixels
    (NaN = missing) and its camera."""

    path: str
    landmarks: np.ndarray
    camera: Camera


def list_images(folder: str | Path) -> list[Path]:
    """The image files directly in ``folder``, sorted by name."""
    root = Path(folder)
    if not root.is_dir():
        raise InputError(root, "images", "a folder of face images", "no such folder")
    files = sorted(p for p in root.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
    if not files:
        raise InputError(root, "images", f"image files ({', '.join(IMAGE_SUFFIXES)})", "none")
    return files


def split_names(names: list[str], val_fraction: float, seed: int) -> tuple[list[str], list[str]]:
    """(train, validation): a name goes to validation when the hash of (seed, name) falls in the
    first ``val_fraction`` of the range, so adding images never moves existing ones."""
    def u(name: str) -> float:
        return int.from_bytes(hashlib.sha256(f"{seed}:{name}".encode()).digest()[:8], "big") / 2**64
    val = [n for n in names if u(n) < val_fraction]
    if val_fraction > 0 and not val and len(names) > 1:
        val = [min(names, key=u)]
    chosen = set(val)
    return [n for n in names if n not in chosen], val


def landmark_table(images: list[Path], cache: Path, detector: str, max_side: int,
                   progress: bool = True) -> tuple[dict[str, Sample], list[tuple[str, str]]]:
    """Landmarks of every image, detected once with :func:`facegeo.detect_landmarks`'s
    detector and cached in ``cache`` (.npz); images that cannot be read or have no face are
    skipped and returned as (name, reason). ``detector="truth"`` reads ``faces.npz`` of a
    ``make-synthetic-faces`` folder instead of detecting."""
    from tqdm import tqdm

    from facegeo.landmarks.detectors import get_detector

    known: dict[str, np.ndarray] = {}
    if detector == "truth":
        truth_path = images[0].parent / TRUTH_FILE
        if not truth_path.is_file():
            raise InputError(truth_path, "landmarks", "the ground truth of make-synthetic-faces", "no such file")
        with np.load(truth_path) as truth:
            known = {str(n): p for n, p in zip(truth["names"], truth["landmarks"])}
    elif cache.is_file():
        with np.load(cache) as data:
            if str(data["detector"]) == detector and int(data["max_side"]) == max_side:
                known = {str(n): p for n, p in zip(data["names"], data["points"])}
    table: dict[str, Sample] = {}
    skipped: list[tuple[str, str]] = []
    det = None if detector == "truth" else get_detector(detector)
    for path in tqdm(images, desc="landmarks", unit="img", disable=not progress, leave=False):
        try:
            photo = load_photo(path, max_side=max_side)
            points = known.get(path.name)
            if points is None:
                if det is None:
                    raise InputError(path, "landmarks", f"an entry in {TRUTH_FILE}", "none")
                points = det.detect(photo.image, str(path)).points
            points = np.asarray(points, np.float32)
            if points.shape != (N_LANDMARKS, 2) or np.isfinite(points).all(1).sum() < 6:
                raise InputError(path, "landmarks", "88 points, at least 6 finite", str(points.shape))
            known[path.name] = points
            w, h = photo.size
            table[path.name] = Sample(str(path), points, Camera.for_image(w, h))
        except FacegeoError as exc:
            skipped.append((path.name, str(exc)))
    if detector != "truth":
        names = sorted(known)
        cache.parent.mkdir(parents=True, exist_ok=True)
        np.savez(cache, names=np.array(names), points=np.stack([known[n] for n in names]) if names else np.zeros((0, 88, 2)),
                 detector=np.array(detector), max_side=np.array(max_side))
    return table, skipped


class FaceCrops(torch.utils.data.Dataset):
    """Crops of ``samples`` as training examples; augmentation (box jitter, mirror, colour gain)
    is a deterministic function of (seed, epoch, index), so a resumed run sees the same data.

    Items: ``image`` (3, S, S) float32 sRGB in [0, 1], ``intrinsics`` (3,) float32 focal, cx, cy
    in crop px, ``landmarks`` (88, 2) float32 crop px (NaN = missing), ``index`` int.
    """

    def __init__(self, samples: list[Sample], size: int, crop_scale: float, augment: bool, seed: int = 0,
                 max_side: int = 2048):
        self.samples, self.size, self.crop_scale = samples, size, crop_scale
        self.augment, self.seed, self.max_side, self.epoch = augment, seed, max_side, 0

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        sample = self.samples[i]
        image = load_photo(sample.path, max_side=self.max_side).image
        points = sample.landmarks.astype(np.float64)
        x0, y0, side = crop_box(points, self.crop_scale)
        rng = np.random.default_rng([self.seed, self.epoch, i])
        flip = False
        if self.augment:
            scale = rng.uniform(0.92, 1.08)
            x0 += side * (rng.uniform(-0.05, 0.05) + (1 - scale) / 2)
            y0 += side * (rng.uniform(-0.05, 0.05) + (1 - scale) / 2)
            side *= scale
            flip = bool(rng.random() < 0.5)
        crop = crop_face(image, (x0, y0, side), self.size).astype(np.float32) / 255.0
        s = self.size / side
        cam = sample.camera
        focal, cx, cy = cam.focal * s, (cam.cx - x0) * s, (cam.cy - y0) * s
        lm = (points - [x0, y0]) * s
        if flip:  # the mirrored photo of a scene is the mirrored scene: swap the sides
            crop = crop[:, ::-1]
            lm = lm[HYBRID_MIRROR]
            lm[:, 0] = self.size - lm[:, 0]
            cx = self.size - cx
        if self.augment:
            gain = rng.uniform(0.8, 1.2) * rng.uniform(0.92, 1.08, size=3)
            crop = np.clip((crop - 0.5) * rng.uniform(0.8, 1.2) + 0.5, 0, 1) * gain
        return {
            "image": torch.from_numpy(np.ascontiguousarray(np.clip(crop, 0, 1).transpose(2, 0, 1), dtype=np.float32)),
            "intrinsics": torch.tensor([focal, cx, cy], dtype=torch.float32),
            "landmarks": torch.from_numpy(lm.astype(np.float32)),
            "index": torch.tensor(i),
        }

