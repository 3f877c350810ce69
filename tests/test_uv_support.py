"""Shared helpers of the facegeo.uv tests: posed model meshes, a surface-painted texture and the
ray-casting visibility oracle (Open3D's RaycastingScene)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from facegeo.camera import Camera, rotation_from_euler

__all__ = ["posed_fit", "painted_texture", "oracle_visible", "psnr"]


def posed_fit(model, yaw=0.0, pitch=0.0, roll=0.0, size=512, distance=700.0, shift=(0.0, 0.0), vertices=None):
    """A fit-like object (``vertices`` camera space, ``camera``) of the model's mean shape (or
    ``vertices``) turned by the Euler angles and placed ``distance`` mm in front of a 40° camera."""
    R = rotation_from_euler(yaw, pitch, roll)
    base = model.mean_shape if vertices is None else vertices
    t = np.array([shift[0], shift[1], -distance])
    V = (np.asarray(base, dtype=np.float64) @ R.T + t).astype(np.float32)
    return SimpleNamespace(vertices=V, camera=Camera.for_image(size, size, 40.0), rotation=R, translation=t)


def painted_texture(model, raster):
    """A smooth colour texture painted on the surface: a function of the model-space position
    (so it is continuous across UV seams), sRGB values in [0.2, 0.8]; (S, S, 3) float32."""
    from facegeo.uv import geometry_maps

    p = geometry_maps(model.mean_shape, model, raster, tangents=False).position.astype(np.float64)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    tex = np.stack([
        0.5 + 0.3 * np.sin(2 * np.pi * x / 40.0) * np.cos(2 * np.pi * y / 50.0),
        0.5 + 0.3 * np.sin(2 * np.pi * (x + z) / 35.0 + 1.0),
        0.5 + 0.25 * np.cos(2 * np.pi * (y - z) / 45.0),
    ], axis=-1)
    return np.where(raster.mask[..., None], tex, 0.0).astype(np.float32)


def oracle_visible(model, fit, raster, unwrapped):
    """Ray-casting visibility of the raster's inside texels: the first hit of the ray from the
    camera centre to the texel's surface point is that point, its triangle faces the camera and
    it projects into the image. Returns (oracle, ours) bool arrays over the inside texels."""
    import open3d as o3d

    from facegeo.uv import geometry_maps

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(fit.vertices, dtype=np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(model.triangles, dtype=np.uint32)))
    inside = raster.inside
    P = geometry_maps(fit.vertices, model, raster, tangents=False).position[inside].astype(np.float32)
    dist = np.linalg.norm(P, axis=1)
    rays = np.concatenate([np.zeros_like(P), P / dist[:, None]], axis=1).astype(np.float32)
    t_hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    first = t_hit >= dist * (1.0 - 1e-5) - 1e-3
    tri = raster.triangle[inside]
    c = fit.vertices[model.triangles].astype(np.float64)
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    facing = (n[tri] * -P.astype(np.float64)).sum(axis=1) > 0
    cam = fit.camera
    x = cam.cx + cam.focal * P[:, 0] / -P[:, 2]
    y = cam.cy - cam.focal * P[:, 1] / -P[:, 2]
    in_image = (-P[:, 2] > 1.0) & (x >= 0) & (x <= cam.width) & (y >= 0) & (y <= cam.height)
    return first & facing & in_image, unwrapped.visible[inside]


def psnr(a, b, mask):
    """PSNR in dB of ``a`` against ``b`` (values in [0, 1]) over ``mask``."""
    mse = float(((a - b)[mask] ** 2).mean())
    return 10.0 * np.log10(1.0 / max(mse, 1e-20))
