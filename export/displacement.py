"""Displacement: vertex normals, bilinear map sampling, baking a displacement map into geometry.

``bake_displacement`` moves every geometry vertex along its smoothed normal (the normalised sum
of the area-weighted normals of its triangles) by the displacement map sampled bilinearly at its
UV. A vertex on a UV seam has one UV per chart: it is sampled in each and moved by the mean, so
both sides of a seam move together and the mesh stays watertight. ``displace`` subdivides first
(:func:`facegeo.export.subdivision.subdivide`), then bakes: the result is the displaced mesh
Python users ask for.

Map convention (DESIGN.md, "Conventions"): row 0 is the top of the UV square; texel (i, j) is centred at
u = (j + 0.5)/W, v = 1 − (i + 0.5)/H. Samples outside the texel centres are clamped to the edge.

Numerical care: normals are accumulated in float64; a vertex whose triangles have no area (or
that no triangle uses) has no normal of its own and takes the mean normal of its neighbours,
and +Z (out of the face) if that is zero too, so it never gets a NaN.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from facegeo.asset import Asset
from facegeo.errors import InputError
from facegeo.export.facevarying import FaceVaryingMesh, as_face_varying, to_trimesh
from facegeo.export.subdivision import subdivide

__all__ = ["vertex_normals", "sample_map", "vertex_values", "bake_displacement", "displace"]

_FALLBACK_NORMAL = np.array([0.0, 0.0, 1.0])


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals, (V, 3) float64, for (V, 3) vertices and (F, 3)
    counter-clockwise triangles. Degenerate cases fall back as described in the module text."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(triangles, dtype=np.int64)
    face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # 2 × area × unit normal
    corners = f.ravel()
    n = np.stack([np.bincount(corners, weights=np.repeat(face_n[:, c], 3), minlength=len(v)) for c in range(3)], axis=1)
    length = np.linalg.norm(n, axis=1)
    scale = np.max(length) if len(length) else 0.0
    bad = length <= 1e-12 * max(scale, 1e-300)
    if bad.any():
        unit = np.zeros_like(n)
        unit[~bad] = n[~bad] / length[~bad, None]
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        adjacency = sp.csr_matrix((np.ones(2 * len(e)), (np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]]))), shape=(len(v), len(v)))
        for _ in range(3):  # a few rings outwards, for clusters of degenerate triangles
            neighbour = adjacency[np.flatnonzero(bad)] @ unit
            nl = np.linalg.norm(neighbour, axis=1)
            good = nl > 1e-12
            idx = np.flatnonzero(bad)[good]
            unit[idx] = neighbour[good] / nl[good, None]
            bad[idx] = False
            if not bad.any():
                break
        unit[bad] = _FALLBACK_NORMAL
        return unit
    return n / length[:, None]


def sample_map(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of an (H, W) or (H, W, C) map at (N, 2) UVs (origin bottom-left, row 0 =
    top): (N,) or (N, C) float64. Coordinates beyond the outer texel centres are clamped."""
    img = np.asarray(image, dtype=np.float64)
    if img.ndim not in (2, 3) or min(img.shape[:2]) < 1:
        raise InputError("<map>", "map", "an (H, W) or (H, W, C) array", str(img.shape))
    uv = np.asarray(uv, dtype=np.float64)
    h, w = img.shape[:2]
    x = np.clip(uv[:, 0] * w - 0.5, 0.0, w - 1.0)
    y = np.clip((1.0 - uv[:, 1]) * h - 0.5, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), max(w - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.int64), max(h - 2, 0))
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx = x - x0
    fy = y - y0
    if img.ndim == 3:
        fx, fy = fx[:, None], fy[:, None]
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def vertex_values(mesh: Any, image: np.ndarray) -> np.ndarray:
    """One value per geometry vertex: the map sampled at each distinct UV of the vertex and
    averaged (seam vertices have several). (V,) or (V, C) float64; a vertex no triangle uses gets 0."""
    fv = as_face_varying(mesh)
    if not fv.has_uv:
        raise InputError("<mesh>", "uv", "a mesh with UVs to sample a map")
    n_uv = len(fv.uv)
    pairs = np.unique(fv.triangles.ravel() * n_uv + fv.uv_triangles.ravel())
    vert, uvi = pairs // n_uv, pairs % n_uv
    samples = sample_map(image, fv.uv[uvi])
    n = len(fv.vertices)
    count = np.maximum(np.bincount(vert, minlength=n), 1).astype(np.float64)
    if samples.ndim == 1:
        return np.bincount(vert, weights=samples, minlength=n) / count
    return np.stack([np.bincount(vert, weights=samples[:, c], minlength=n) for c in range(samples.shape[1])], axis=1) / count[:, None]


def bake_displacement(mesh: Any, displacement_map: np.ndarray | float | None = None, scale_mm: float = 1.0) -> Any:
    """Move every vertex along its smoothed area-weighted normal by ``scale_mm ×`` the map.

    ``mesh``: an :class:`Asset`, a :class:`trimesh.Trimesh` with UVs or a ``FaceVaryingMesh``;
    the same type is returned (a Trimesh with one vertex per (vertex, UV) pair and the displaced
    mesh's normals). ``displacement_map``: (H, W) float array (millimetres when ``scale_mm`` is 1,
    DESIGN.md, "Conventions"), or a number (a uniform offset), or None for an Asset's own
    ``displacement`` map or constant. When the Asset's own displacement is baked it is removed
    from the returned Asset (so it is not applied twice) and ``metadata["displacement_baked"]``
    records the scale.

    Raises:
        InputError: no UVs, no map (None and the Asset has none), a map that is not 2-D or has
            NaN/inf, or a non-finite scale.
    """
    fv = as_face_varying(mesh)
    own = False
    if displacement_map is None:
        if isinstance(mesh, Asset) and "displacement" in mesh.maps:
            displacement_map, own = mesh.maps["displacement"], True
        elif isinstance(mesh, Asset) and "displacement" in mesh.constants:
            displacement_map, own = float(mesh.constants["displacement"]), True
        else:
            raise InputError("<mesh>", "displacement_map", "a displacement map (the mesh has none of its own)")
    elif isinstance(mesh, Asset):
        own = displacement_map is mesh.maps.get("displacement")
    if not np.isfinite(scale_mm):
        raise InputError("<bake_displacement>", "scale_mm", "a finite number", repr(scale_mm))
    if np.ndim(displacement_map) == 0:
        offsets = np.full(len(fv.vertices), float(displacement_map))
    else:
        dmap = np.asarray(displacement_map, dtype=np.float64)
        if dmap.ndim == 3 and dmap.shape[2] == 1:
            dmap = dmap[:, :, 0]
        if dmap.ndim != 2 or min(dmap.shape) < 1:
            raise InputError("<map>", "displacement_map", "an (H, W) array", str(dmap.shape))
        if not np.all(np.isfinite(dmap)):
            raise InputError("<map>", "displacement_map", "finite values", "NaN/inf texels")
        offsets = vertex_values(fv, dmap)
    normals = vertex_normals(fv.vertices, fv.triangles)
    moved = fv.vertices + normals * (offsets * float(scale_mm))[:, None]
    out = FaceVaryingMesh(moved, fv.triangles, fv.uv, fv.uv_triangles)
    if isinstance(mesh, Asset):
        maps, constants, metadata = dict(mesh.maps), dict(mesh.constants), dict(mesh.metadata)
        if own:
            maps.pop("displacement", None)
            constants.pop("displacement", None)
            metadata["displacement_baked"] = {"scale_mm": float(scale_mm), "level": int(metadata.get("subdivision_level", 0))}
        return Asset(moved, mesh.triangles, mesh.uv, mesh.uv_triangles, maps=maps, constants=constants, name=mesh.name, metadata=metadata)
    if isinstance(mesh, FaceVaryingMesh):
        return out
    return to_trimesh(out, material=getattr(getattr(mesh, "visual", None), "material", None))


def displace(mesh: Any, displacement_map: np.ndarray | float | None = None, level: int = 2, scale_mm: float = 1.0,
             *, uv_interpolation: str = "surface") -> Any:
    """Subdivide ``mesh`` ``level`` times (Loop, UVs carried) and bake the displacement map.

    Returns the input's type: an :class:`Asset` (without its displacement map once baked; use
    :func:`facegeo.export.to_trimesh` for a Trimesh) or a :class:`trimesh.Trimesh` with UVs.
    ``displacement_map`` (H, W) in map units × ``scale_mm`` = millimetres; None takes an Asset's
    own. See :func:`subdivide` and :func:`bake_displacement`.
    """
    if displacement_map is None and isinstance(mesh, Asset):
        displacement_map = mesh.maps.get("displacement", mesh.constants.get("displacement"))
        if displacement_map is None:
            raise InputError("<mesh>", "displacement_map", "a displacement map (the asset has none of its own)")
        fine = subdivide(mesh, level, uv_interpolation=uv_interpolation)
        return bake_displacement(fine, None, scale_mm)
    fine = subdivide(mesh, level, uv_interpolation=uv_interpolation)
    if isinstance(mesh, Asset) and displacement_map is mesh.maps.get("displacement"):
        displacement_map = fine.maps["displacement"]  # same array; keeps the "own map" identity
    return bake_displacement(fine, displacement_map, scale_mm)
