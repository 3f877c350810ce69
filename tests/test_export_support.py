"""Shared helpers of the export tests (no tests here): synthetic assets on the bundled model."""

from __future__ import annotations

import functools

import numpy as np

from facegeo.asset import Asset
from facegeo.model_files import load_model


@functools.lru_cache(maxsize=1)
def model():
    return load_model()


def synthetic_maps(size: int = 64, seed: int = 0) -> dict[str, np.ndarray]:
    """Smooth, non-constant maps of every kind (float32, image convention)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    phase = rng.uniform(0, 2 * np.pi, 4).astype(np.float32)
    albedo = np.stack([0.6 + 0.2 * x, 0.45 + 0.2 * y, 0.35 + 0.1 * np.sin(6 * x + phase[0])], axis=-1)
    normal = np.stack([0.2 * np.sin(9 * x + phase[1]), 0.2 * np.cos(7 * y + phase[2]), np.ones_like(x)], axis=-1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    return {
        "albedo": albedo.astype(np.float32),
        "normal": normal.astype(np.float32),
        "roughness": (0.35 + 0.3 * x * y).astype(np.float32),
        "specular": (0.4 + 0.3 * y).astype(np.float32),
        "displacement": (0.4 * np.sin(23 * x + phase[3]) * np.sin(19 * y)).astype(np.float32),  # mm
    }


def ict_asset(maps: dict | None = None, constants: dict | None = None, size: int = 64, name: str = "face") -> Asset:
    """The bundled model's mean shape with face-varying UVs and synthetic maps."""
    m = model()
    if maps is None:
        maps = synthetic_maps(size)
    return Asset(m.mean_shape, m.triangles, m.uv, m.uv_triangles, maps=maps, constants=constants or {}, name=name)


def grid_mesh(n: int = 4, size: float = 10.0):
    """A flat n×n-quad grid in the XY plane (z = 0, normal +Z), UV = XY / size: (V, F, UV, UVF)."""
    ys, xs = np.mgrid[0 : n + 1, 0 : n + 1]
    v = np.stack([xs.ravel() * size / n, ys.ravel() * size / n, np.zeros(xs.size)], axis=1)
    f = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            f += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    f = np.array(f)
    return v, f, v[:, :2] / size, f.copy()
