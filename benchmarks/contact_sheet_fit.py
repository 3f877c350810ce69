"""Clay renders of the fitted shape, before and after the MAP fit, on the real sample photos.

    python benchmarks/contact_sheet_fit.py [-o docs/fit_clay_before_after.jpg]

Rows: the photos of :func:`sample_photos.sample_photos`. Columns: the photo, then the shape of
the fit before the MAP change (git, unbounded expressions) and of the MAP fit, each rendered
unposed in model space from the front, three-quarter (35°) and profile (80°) with the project's
z-buffer (``facegeo.uv.rasterize_mesh``) and a grey Lambert ("clay") shading.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fit_priors import previous_fit_landmarks  # noqa: E402
from sample_photos import sample_photos  # noqa: E402

from facegeo import Camera, fit_landmarks, load_model, load_photo  # noqa: E402
from facegeo.camera import rotation_from_euler  # noqa: E402
from facegeo.landmarks import get_detector  # noqa: E402
from facegeo.uv import rasterize_mesh  # noqa: E402

TILE = 256
LIGHT = np.array([0.3, 0.4, 0.87]) / np.linalg.norm([0.3, 0.4, 0.87])


def clay_views(model, vertices: np.ndarray) -> np.ndarray:
    """(TILE, 3·TILE) uint8: ``vertices`` (V, 3) model space seen from 0°, 35° and 80° of yaw."""
    camera = Camera.for_image(TILE, TILE)
    centred = vertices - np.array([0.0, vertices[model.landmark_indices[27], 1] - 40.0, vertices[model.landmark_indices[30], 2]])
    tiles = []
    for yaw in (0.0, 35.0, 80.0):
        posed = centred @ rotation_from_euler(yaw, 0.0, 0.0).T + np.array([0.0, 0.0, -700.0])
        triangle, barycentric, _ = rasterize_mesh(posed, model.triangles, camera)
        normals = model.vertex_normals(torch.from_numpy(posed.astype(np.float32))).numpy()
        covered = triangle >= 0
        n = (normals[model.triangles[triangle[covered]]] * barycentric[covered][..., None]).sum(1)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        tile = np.full((TILE, TILE), 40, np.uint8)
        tile[covered] = np.clip(60 + 190 * np.clip(n @ LIGHT, 0, 1), 0, 255).astype(np.uint8)
        tiles.append(tile)
    return np.concatenate(tiles, axis=1)


def photo_thumbnail(image: np.ndarray) -> np.ndarray:
    """(TILE, TILE) uint8: an (H, W, 3) uint8 RGB photo in grey, fitted into the tile's top-left."""
    h, w = image.shape[:2]
    scale = TILE / max(h, w)
    thumb = cv2.resize(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), (round(w * scale), round(h * scale)), interpolation=cv2.INTER_AREA)
    return np.pad(thumb, ((0, TILE - thumb.shape[0]), (0, TILE - thumb.shape[1])))


def write_sheet(rows: list[np.ndarray], labels: tuple[str, str], output: Path, quality: int) -> None:
    """Stack the rows, label the two groups of clay columns, write the JPEG (``quality``)."""
    sheet = np.concatenate(rows, axis=0)
    for column, label in zip((1, 4), labels):
        cv2.putText(sheet, label, (column * TILE + 10, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, 255, 1)
    output.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(output), sheet, [cv2.IMWRITE_JPEG_QUALITY, quality])
    print(f"wrote {output}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=Path("docs/fit_clay_before_after.jpg"))
    args = parser.parse_args()
    model = load_model()
    before = previous_fit_landmarks()
    detector = get_detector("hybrid")
    rows = []
    for path in sample_photos():
        photo = load_photo(path)
        h, w = photo.image.shape[:2]
        camera = Camera.for_image(w, h)
        points = detector.detect(photo.image).points
        old = before(model, points, camera)
        old_shape = model.shape(torch.from_numpy(old.alpha), torch.from_numpy(old.delta)).numpy()
        new = fit_landmarks(model, points, camera)
        rows.append(np.concatenate([photo_thumbnail(photo.image), clay_views(model, old_shape), clay_views(model, new.shape_vertices)], axis=1))
    write_sheet(rows, ("before: unbounded expressions", "MAP fit: bounded expressions, noise-weighted priors"), args.output, 85)


if __name__ == "__main__":
    main()
