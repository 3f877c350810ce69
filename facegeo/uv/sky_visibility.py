"""Ambient occlusion of a triangle mesh: how much of a uniform sky each vertex receives past
the mesh itself.

A Lambertian surface under a uniform environment of radiance L receives the irradiance
π · L · A, where A is the cosine-weighted fraction of the hemisphere around its normal from
which a ray escapes the mesh (1 on a convex surface, less in a concavity: below the chin, beside
the nose, in the eye sockets). :func:`ambient_occlusion` estimates A per vertex by casting
:data:`AO_DIRECTIONS` rays from each vertex into a cosine-weighted set of directions (Malley's
method: a Fibonacci spiral on the unit disc lifted onto the hemisphere, so each ray carries the
same weight) with Open3D's ray casting (Embree). Every vertex uses the same directions in its
own tangent frame, so neighbouring vertices see nearly the same rays and the estimate varies
smoothly over the surface (its error is a bias of ~1/``directions``, not per-vertex noise).
"""

from __future__ import annotations

import numpy as np

from facegeo.normals import vertex_normals

__all__ = ["ambient_occlusion", "hemisphere_directions", "AO_DIRECTIONS", "AO_OFFSET_MM"]

#: Rays per vertex.
AO_DIRECTIONS = 64
#: Rays start this far along the vertex normal (mm), clear of the vertex's own triangles.
AO_OFFSET_MM = 0.3


def hemisphere_directions(count: int) -> np.ndarray:
    """(count, 3) float32 unit directions about +Z, cosine-weighted and stratified: the points
    of a Fibonacci spiral on the unit disc (equal areas) lifted onto the hemisphere (z = √(1 − r²))."""
    k = np.arange(count) + 0.5
    r = np.sqrt(k / count)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * k
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - r * r)], axis=1).astype(np.float32)


def ambient_occlusion(vertices: np.ndarray, triangles: np.ndarray, directions: int = AO_DIRECTIONS,
                      offset_mm: float = AO_OFFSET_MM) -> np.ndarray:
    """Cosine-weighted sky visibility of each vertex of a triangle mesh.

    Args:
        vertices: (V, 3) float vertex positions, mm. triangles: (F, 3) int vertex indices; both
            sides of a triangle occlude.
        directions: rays per vertex. offset_mm: where each ray starts along the vertex normal
            (:func:`facegeo.normals.vertex_normals`).
    Returns:
        (V,) float32 in [0, 1]: the share of the vertex's rays that leave the mesh (1: open sky).
    """
    import open3d as o3d  # here only: an even light never needs ray casting

    v = np.ascontiguousarray(vertices, np.float32)
    f = np.ascontiguousarray(triangles, np.uint32)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"ambient_occlusion: expected (V, 3) vertices and (F, 3) triangles, got {v.shape} and {f.shape}")
    if len(v) == 0 or len(f) == 0:
        return np.ones(len(v), np.float32)
    normal = vertex_normals(v, f).astype(np.float32)
    helper = np.where(np.abs(normal[:, :1]) < 0.9, np.float32([[1, 0, 0]]), np.float32([[0, 1, 0]]))
    tangent = np.cross(normal, helper)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    bitangent = np.cross(normal, tangent)
    local = hemisphere_directions(directions)
    ray_directions = (local[None, :, 0:1] * tangent[:, None] + local[None, :, 1:2] * bitangent[:, None]
                      + local[None, :, 2:3] * normal[:, None])  # (V, K, 3)
    origins = np.broadcast_to((v + offset_mm * normal)[:, None], ray_directions.shape)
    rays = np.concatenate([origins, ray_directions], axis=-1).reshape(-1, 6)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(f))
    blocked = scene.test_occlusions(o3d.core.Tensor(np.ascontiguousarray(rays, np.float32))).numpy().reshape(len(v), directions)
    return (1.0 - blocked.mean(axis=1)).astype(np.float32)
