"""Displacement: baking a displacement map into geometry.

``bake_displacement`` moves every geometry vertex along its smoothed normal
(:func:`facegeo.normals.vertex_normals`: finite unit vectors even at degenerate vertices) by the
displacement map sampled bilinearly at its UV (:func:`facegeo.uv.texels.sample_uv`). A vertex on a
UV seam has one UV per chart: it is sampled in each and moved by the mean, so both sides of a seam
move together and the mesh stays watertight. ``displace`` subdivides first
(:func:`facegeo.export.subdivision.subdivide`), then bakes: the result is the displaced mesh
Python users ask for.

Map convention (DESIGN.md, "Conventions"; in code :mod:`facegeo.uv.texels`): row 0 is the top of
the UV square; beyond the outer texel centres the edge texels repeat.
"""

from __future__ import annotations

import numpy as np

from facegeo.asset import Asset
from facegeo.errors import InputError
from facegeo.export.facevarying import FaceVaryingMesh, as_face_varying
from facegeo.export.subdivision import subdivide
from facegeo.normals import vertex_normals
from facegeo.uv.texels import sample_uv

__all__ = ["vertex_values", "bake_displacement", "displace"]


def vertex_values(mesh: Asset | FaceVaryingMesh, image: np.ndarray) -> np.ndarray:
    """One value per geometry vertex: the map sampled at each distinct UV of the vertex and
    averaged (seam vertices have several). (V,) or (V, C) float64; a vertex no triangle uses gets 0."""
    fv = as_face_varying(mesh)
    if not fv.has_uv:
        raise InputError("<mesh>", "uv", "a mesh with UVs to sample a map")
    n_uv = len(fv.uv)
    pairs = np.unique(fv.triangles.ravel() * n_uv + fv.uv_triangles.ravel())
    vert, uvi = pairs // n_uv, pairs % n_uv
    samples = sample_uv(image, fv.uv[uvi]).astype(np.float64)
    n = len(fv.vertices)
    count = np.maximum(np.bincount(vert, minlength=n), 1).astype(np.float64)
    if samples.ndim == 1:
        return np.bincount(vert, weights=samples, minlength=n) / count
    return np.stack([np.bincount(vert, weights=samples[:, c], minlength=n) for c in range(samples.shape[1])], axis=1) / count[:, None]


def bake_displacement(mesh: Asset | FaceVaryingMesh, displacement_map: np.ndarray | float | None = None,
                      scale_mm: float = 1.0) -> Asset | FaceVaryingMesh:
    """Move every vertex along its smoothed area-weighted normal by ``scale_mm ×`` the map.

    ``mesh``: an :class:`Asset` (returns an Asset) or a ``FaceVaryingMesh`` with UVs (returns
    one). ``displacement_map``: (H, W) float array (millimetres when ``scale_mm`` is 1,
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
    return out


def displace(mesh: Asset | FaceVaryingMesh, displacement_map: np.ndarray | float | None = None, level: int = 2,
             scale_mm: float = 1.0, *, uv_interpolation: str = "surface") -> Asset | FaceVaryingMesh:
    """Subdivide ``mesh`` ``level`` times (Loop, UVs carried) and bake the displacement map.

    Returns an :class:`Asset` for an Asset (without its displacement map once baked) and a
    ``FaceVaryingMesh`` otherwise; :func:`facegeo.export.to_trimesh` makes a Trimesh of either.
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
