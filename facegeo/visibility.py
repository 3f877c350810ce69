"""Per-vertex visibility of a posed mesh from a point-splatting z-buffer plus a facing test.

Why by hand: the fit needs vertex visibility many times per second on a CPU, for meshes whose
triangles project to about a pixel; splatting a few barycentric samples per triangle into a
depth buffer with ``np.minimum.at`` is exact enough at that density, has no dependency on a GL
context, and costs a few milliseconds. The exact triangle rasteriser lives in ``facegeo.uv``.
"""

from __future__ import annotations

import numpy as np

from facegeo.camera import Camera, to_pixels

__all__ = ["vertex_visibility"]

# Barycentric samples per triangle: the three vertices, the centroid and the edge midpoints.
_SAMPLES = np.array(
    [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1 / 3, 1 / 3, 1 / 3], [0.5, 0.5, 0], [0, 0.5, 0.5], [0.5, 0, 0.5]],
    dtype=np.float64,
)


def _samples(corners: np.ndarray) -> np.ndarray:
    """(F, 7, 3) float64: :data:`_SAMPLES` of each triangle's (F, 3, 3) ``corners``, each written
    out in :data:`_SAMPLES`' order (the weights' zero terms left out): the same numbers as the
    weighted sums, in a quarter of ``np.einsum``'s time."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    out = np.empty((len(corners), len(_SAMPLES), corners.shape[2]))
    out[:, 0], out[:, 1], out[:, 2] = a, b, c
    third = _SAMPLES[3, 0]
    out[:, 3] = (third * a + third * b) + third * c
    out[:, 4] = 0.5 * a + 0.5 * b
    out[:, 5] = 0.5 * b + 0.5 * c
    out[:, 6] = 0.5 * a + 0.5 * c
    return out


def vertex_visibility(
    vertices_cam: np.ndarray,
    triangles: np.ndarray,
    normals_cam: np.ndarray,
    camera: Camera,
    max_side: int = 512,
    depth_tolerance_mm: float = 2.0,
    min_facing: float = 0.05,
) -> np.ndarray:
    """Which vertices the camera sees.

    Args:
        vertices_cam: (V, 3) camera-space positions in mm (camera looks down −Z).
        triangles: (F, 3) int64.
        normals_cam: (V, 3) unit vertex normals in camera space.
        camera: intrinsics; the buffer is the image scaled so its longer side is ≤ ``max_side``.
        depth_tolerance_mm: a vertex is unoccluded if its depth is within this of the buffer.
        min_facing: minimum cosine between the normal and the direction to the camera.
    Returns:
        (V,) bool: in front of the camera, inside the image, facing it and not occluded.
    """
    v = np.asarray(vertices_cam, dtype=np.float64)
    scale = min(1.0, max_side / max(camera.width, camera.height))
    w, h = max(1, int(round(camera.width * scale))), max(1, int(round(camera.height * scale)))
    depth = -v[:, 2]
    u, r = (to_pixels(v, camera) * scale).T
    in_front = depth > 1e-3

    tri = np.asarray(triangles)
    tri_ok = in_front[tri].all(axis=1)
    tri = tri[tri_ok]
    pts = np.stack([u, r, depth], axis=1)[tri]  # (F, 3 corners, 3)
    samples = _samples(pts).reshape(-1, 3)
    cols, rows = np.floor(samples[:, 0]).astype(np.int64), np.floor(samples[:, 1]).astype(np.int64)
    inside = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
    zbuf = np.full(h * w, np.inf)
    np.minimum.at(zbuf, rows[inside] * w + cols[inside], samples[inside, 2])

    vc, vr = np.floor(u).astype(np.int64), np.floor(r).astype(np.int64)
    in_image = in_front & (vc >= 0) & (vc < w) & (vr >= 0) & (vr < h)
    visible = np.zeros(len(v), dtype=bool)
    idx = np.flatnonzero(in_image)
    visible[idx] = depth[idx] <= zbuf[vr[idx] * w + vc[idx]] + depth_tolerance_mm
    to_camera = -v / np.linalg.norm(v, axis=1, keepdims=True).clip(1e-9)
    facing = np.einsum("vc,vc->v", np.asarray(normals_cam, dtype=np.float64), to_camera) > min_facing
    return visible & facing
