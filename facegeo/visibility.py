"""Per-vertex visibility of a posed mesh from a point-splatting z-buffer plus a facing test.

Why by hand: the fit needs vertex visibility many times per second on a CPU, for meshes whose
triangles project to about a pixel; splatting a few barycentric samples per triangle into a
depth buffer with ``np.minimum.at`` is exact enough at that density, has no dependency on a GL
context, and costs a few milliseconds. The exact triangle rasteriser lives in ``facegeo.uv``.
"""

from __future__ import annotations

import numpy as np

from facegeo.camera import Camera, to_pixels

__all__ = ["vertex_visibility", "facing_cosine"]

def _splat_points(values: np.ndarray, tri: np.ndarray, used: np.ndarray) -> np.ndarray:
    """(N,) float64: the splatted samples of per-vertex ``values`` (V,) float64 on the triangles
    ``tri`` (F, 3): each ``used`` (V,) bool vertex once (a corner shared by several triangles
    splats the same number), then each triangle's centroid and edge midpoints, one row of F per
    kind. Each coordinate is built alone, so the rows are contiguous copies, not strided writes
    into an (F, 7, 3) array."""
    a, b, c = values[tri[:, 0]], values[tri[:, 1]], values[tri[:, 2]]
    out = np.empty(int(used.sum()) + 4 * len(tri))
    n = len(out) - 4 * len(tri)
    out[:n] = values[used]
    rows = out[n:].reshape(4, len(tri))
    third = 1 / 3
    rows[0] = (third * a + third * b) + third * c
    rows[1] = 0.5 * a + 0.5 * b
    rows[2] = 0.5 * b + 0.5 * c
    rows[3] = 0.5 * a + 0.5 * c
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
    # Each in-front triangle's corners, centroid and edge midpoints, splatted (the minimum over
    # a pixel's samples does not depend on their order or on a corner counted once or thrice).
    used = np.zeros(len(v), dtype=bool)
    used[tri] = True
    cols = np.floor(_splat_points(u, tri, used)).astype(np.int64)
    rows = np.floor(_splat_points(r, tri, used)).astype(np.int64)
    inside = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
    zbuf = np.full(h * w, np.inf)
    np.minimum.at(zbuf, rows[inside] * w + cols[inside], _splat_points(depth, tri, used)[inside])

    vc, vr = np.floor(u).astype(np.int64), np.floor(r).astype(np.int64)
    in_image = in_front & (vc >= 0) & (vc < w) & (vr >= 0) & (vr < h)
    visible = np.zeros(len(v), dtype=bool)
    idx = np.flatnonzero(in_image)
    visible[idx] = depth[idx] <= zbuf[vr[idx] * w + vc[idx]] + depth_tolerance_mm
    return visible & (facing_cosine(v, normals_cam) > min_facing)


def facing_cosine(points_cam: np.ndarray, normals_cam: np.ndarray) -> np.ndarray:
    """(N,) float64: the cosine between each unit normal (N, 3) and the direction from its point
    (N, 3) mm, camera space, to the camera at the origin."""
    v = np.asarray(points_cam, dtype=np.float64)
    to_camera = -v / np.linalg.norm(v, axis=1, keepdims=True).clip(1e-9)
    return np.einsum("vc,vc->v", np.asarray(normals_cam, dtype=np.float64), to_camera)
