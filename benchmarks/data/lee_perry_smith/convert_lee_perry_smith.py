"""Makes this folder's scan files from three.js's copy of the Infinite-Realities head scan.

    python benchmarks/data/lee_perry_smith/convert_lee_perry_smith.py THREE_JS_LEEPERRYSMITH_FOLDER

The folder is three.js's ``examples/obj/leeperrysmith/`` (``LeePerrySmith.obj``, ``Map-COL.jpg``,
``LeePerrySmith_License.txt``; the SHA-256 of each is checked against :data:`SOURCES`). Written
here:

* ``lee_perry_smith.obj.xz``: the scan's mesh with its UVs, every quad split into two triangles
  along its first diagonal, coordinates in the file's own units (xz-compressed OBJ);
* ``Map-COL.jpg`` and ``LeePerrySmith_License.txt``: copied unchanged;
* ``landmarks.json``: 68 iBUG landmarks on the scan, in the same units, and the scale that
  takes those units to millimetres.

The landmarks are detected, not annotated by hand: the scan's unshaded colour map is ray-cast
from the front (every pixel shows the texture colour at the surface point it sees), facegeo's
hybrid detector finds the 68 points in that image, and each is cast back onto the surface. Twice:
the second image is taken facing the frontal pose that the first landmarks give.

The file's units are ZBrush's (its header says it was auto-scaled), not millimetres. The scale
is an estimate: the one that best fits the scan's inner-face landmarks (iBUG 17-67) onto the
ICT-FaceKit mean shape's by a similarity transform, i.e. the scan is taken as an average-sized
head. Good enough for renders at a given distance and for colour comparisons; not for metric
shape errors.
"""

from __future__ import annotations

import hashlib
import json
import lzma
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent))
from scan_renders import _kabsch, cast_rays  # noqa: E402

from facegeo import Camera, load_model  # noqa: E402
from facegeo.photo import load_photo  # noqa: E402
from facegeo.landmarks import detect_landmarks  # noqa: E402
from facegeo.landmarks.scheme import INNER_FACE, N_IBUG  # noqa: E402
from facegeo.mesh_io import obj_text  # noqa: E402

#: The files of three.js's ``examples/obj/leeperrysmith/`` used here, with their SHA-256.
SOURCES = {
    "LeePerrySmith.obj": "4b3daaeabb626ab857d8bd0f253054f9ca9a406d17917b681fd331158522aab2",
    "Map-COL.jpg": "e976d73b31407f8d0967412bf468019ed26a5d5a32cf5811aabff7e816458a65",
    "LeePerrySmith_License.txt": "1442c59483c1a5689308796a7244e912bd15a5dd25f3b894cdc57d22e8c25894",
}
#: The landmark images: size (px) and the camera's distance in head heights.
IMAGE = 768
DISTANCE_HEADS = 4.0


def read_quad_obj(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(vertices (V, 3), triangles (F, 3), uv (T, 2), uv_triangles (F, 3)) of an OBJ whose faces
    are triangles or quads with ``v/vt`` corners; a quad a b c d becomes (a, b, c), (a, c, d)."""
    vertices, uv, faces, uv_faces = [], [], [], []
    for line in path.read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            vertices.append([float(x) for x in parts[1:4]])
        elif parts[0] == "vt":
            uv.append([float(x) for x in parts[1:3]])
        elif parts[0] == "f":
            corners = [c.split("/") for c in parts[1:]]
            if len(corners) not in (3, 4) or any(len(c) < 2 or not c[1] for c in corners):
                raise ValueError(f"{path}: a face with {len(corners)} corners or without UVs: {line!r}")
            v = [int(c[0]) - 1 for c in corners]
            t = [int(c[1]) - 1 for c in corners]
            for i in range(1, len(v) - 1):
                faces.append([v[0], v[i], v[i + 1]])
                uv_faces.append([t[0], t[i], t[i + 1]])
    return np.array(vertices), np.array(faces, np.int64), np.array(uv), np.array(uv_faces, np.int64)


def colour_image(vertices, triangles, uv, uv_triangles, texture, rotation, translation, camera) -> np.ndarray:
    """(H, W, 3) uint8: the texture colour seen at each pixel (grey where the ray misses)."""
    points, hit = cast_rays(vertices, triangles, rotation, translation, camera)
    image = np.full((camera.height, camera.width, 3), 128, np.uint8)
    found = hit >= 0
    tri = hit[found]
    p = points[found].astype(np.float64)
    a, b, c = (vertices[triangles[tri, k]] for k in range(3))
    # barycentric coordinates of the hit points in their triangles
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = d00 * d11 - d01 * d01
    w1 = (d11 * d20 - d01 * d21) / den
    w2 = (d00 * d21 - d01 * d20) / den
    w0 = 1.0 - w1 - w2
    st = w0[:, None] * uv[uv_triangles[tri, 0]] + w1[:, None] * uv[uv_triangles[tri, 1]] + w2[:, None] * uv[uv_triangles[tri, 2]]
    h, w = texture.shape[:2]
    x = np.clip(np.round(st[:, 0] * w - 0.5), 0, w - 1).astype(int)
    y = np.clip(np.round((1.0 - st[:, 1]) * h - 0.5), 0, h - 1).astype(int)
    # shaded by a light at the camera (detectors read the face's relief from its shading)
    normal = np.cross(b - a, c - a)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    facing = np.abs(normal @ rotation[2])
    image[found] = np.clip(texture[y, x] * (0.35 + 0.65 * facing[:, None]), 0, 255).astype(np.uint8)
    return image


def landmarks_3d(vertices, triangles, uv, uv_triangles, texture, rotation, size) -> np.ndarray:
    """(68, 3): the iBUG landmarks detected in the colour image seen along ``rotation`` and cast
    back onto the surface (file units)."""
    centre = vertices.mean(0)
    focal = 2.0 * IMAGE * DISTANCE_HEADS  # the head spans about half the image
    camera = Camera(focal=focal, cx=IMAGE / 2, cy=IMAGE / 2, width=IMAGE, height=IMAGE)
    translation = np.array([0.0, 0.0, -DISTANCE_HEADS * size]) - rotation @ centre
    image = colour_image(vertices, triangles, uv, uv_triangles, texture, rotation, translation, camera)
    pixels = detect_landmarks(image)[:N_IBUG] + 0.5  # detector: pixel centres at integers; rays: at +0.5
    points, hit = cast_rays(vertices, triangles, rotation, translation, camera, pixels)
    for _ in range(20):  # a jaw point on the silhouette that misses: moved towards the face, 1 px a step
        if (hit >= 0).all():
            return points.astype(np.float64)
        miss = hit < 0
        inward = pixels.mean(0) - pixels[miss]
        pixels[miss] += inward / np.linalg.norm(inward, axis=1, keepdims=True)
        points[miss], hit[miss] = cast_rays(vertices, triangles, rotation, translation, camera, pixels[miss])
    raise RuntimeError(f"landmarks off the scan: {np.flatnonzero(hit < 0).tolist()}")


def main() -> None:
    source = Path(sys.argv[1])
    for name, digest in SOURCES.items():
        found = hashlib.sha256((source / name).read_bytes()).hexdigest()
        if found != digest:
            raise SystemExit(f"{source / name}: sha256 {found}, expected {digest}")
    vertices, triangles, uv, uv_triangles = read_quad_obj(source / "LeePerrySmith.obj")
    texture = load_photo(source / "Map-COL.jpg", max_side=4096).image
    size = float(np.ptp(vertices[:, 1]))
    model = load_model()
    target = model.mean_shape[model.landmark_indices[INNER_FACE]].astype(np.float64)
    rotation = np.eye(3)  # the file faces +Z with +Y up (as three.js shows it)
    for _ in range(2):
        points = landmarks_3d(vertices, triangles, uv, uv_triangles, texture, rotation, size)
        rotation = _kabsch(points[INNER_FACE], target)
    inner = points[INNER_FACE] - points[INNER_FACE].mean(0)
    scale = float(np.sqrt(((target - target.mean(0)) ** 2).sum() / (inner ** 2).sum()))
    with lzma.open(HERE / "lee_perry_smith.obj.xz", "wt", preset=9) as f:
        f.write(obj_text(vertices, triangles, uv, uv_triangles, digits=6, comment=False))
    for name in ("Map-COL.jpg", "LeePerrySmith_License.txt"):
        (HERE / name).write_bytes((source / name).read_bytes())
    record = {"points": np.round(points, 6).tolist(), "order": "iBUG-68", "units": "the OBJ's",
              "scale_to_mm": round(scale, 4),  # copied into head_scans.SCANS (load_scan checks)
              "how": "facegeo's hybrid detector on the unshaded colour map ray-cast from the front, cast back onto the "
                     "surface; scale: similarity fit of iBUG 17-67 onto the ICT-FaceKit mean shape (an average-sized head)"}
    (HERE / "landmarks.json").write_text(json.dumps(record, indent=1))
    print(f"{len(vertices)} vertices, {len(triangles)} triangles, scale {scale:.2f} mm per unit")


if __name__ == "__main__":
    main()
