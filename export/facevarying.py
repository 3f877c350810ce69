"""Face-varying triangle meshes: the arrays every exporter works on, and trimesh conversion.

A face-varying mesh is four arrays (DESIGN.md, "Conventions"):

* ``vertices`` (V, 3) float, millimetres: the geometry, one entry per surface point, so the
  surface is watertight wherever the triangles share vertices;
* ``triangles`` (F, 3) int64, counter-clockwise seen from outside;
* ``uv`` (T, 2) float, origin bottom-left, and ``uv_triangles`` (F, 3) int64: the UV corner of
  each triangle corner. A vertex on a UV seam has several UV entries (one per chart).

The pair (vertex index, UV index) of a triangle corner is a *wedge*. Formats that have one
attribute set per vertex (glTF, trimesh) get one output vertex per wedge.

The functions of ``facegeo.export`` take and return an :class:`~facegeo.asset.Asset` (the
project's mesh type, with its maps) or these arrays (:class:`FaceVaryingMesh`), never a third
party's type: trimesh is reached only through the two conversions here. A
:class:`trimesh.Trimesh` stores seams by duplicating vertices; :func:`from_trimesh` welds
vertices at exactly the same position back into one geometry vertex (so the result is watertight
again) and keeps each duplicate's UV as a face-varying UV. Vertices that sit at the same position
but were meant to stay apart are welded too: keep an :class:`~facegeo.asset.Asset` to keep an
exact topology.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from facegeo.asset import Asset
from facegeo.errors import InputError
from facegeo.normals import vertex_normals

__all__ = ["FaceVaryingMesh", "as_face_varying", "wedges", "to_trimesh", "from_trimesh"]


@dataclass
class FaceVaryingMesh:
    """The four arrays of a face-varying mesh (float64 / int64); ``uv`` and ``uv_triangles``
    are both None for a mesh without UVs."""

    vertices: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray | None = None
    uv_triangles: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64)
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.int64)
        if (self.uv is None) != (self.uv_triangles is None):
            raise InputError("<mesh>", "uv", "uv and uv_triangles both given or both None")
        if self.uv is not None:
            self.uv = np.ascontiguousarray(self.uv, dtype=np.float64)
            self.uv_triangles = np.ascontiguousarray(self.uv_triangles, dtype=np.int64)
        self.check()

    @property
    def has_uv(self) -> bool:
        return self.uv is not None

    def check(self, source: str = "<mesh>") -> None:
        """Raise :class:`InputError` for wrong shapes, out-of-range indices or non-finite values."""
        v, f = self.vertices, self.triangles
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
            raise InputError(source, "vertices", "shape (V, 3) with V > 0", str(v.shape))
        if not np.all(np.isfinite(v)):
            raise InputError(source, "vertices", "finite values", "NaN/inf")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or f.min() < 0 or f.max() >= len(v):
            raise InputError(source, "triangles", f"shape (F, 3) with indices in [0, {len(v)})", str(f.shape))
        if self.uv is not None:
            uv, ut = self.uv, self.uv_triangles
            if uv.ndim != 2 or uv.shape[1] != 2 or len(uv) == 0 or not np.all(np.isfinite(uv)):
                raise InputError(source, "uv", "finite (T, 2) coordinates", str(uv.shape))
            if ut.shape != f.shape or ut.min() < 0 or ut.max() >= len(uv):
                raise InputError(source, "uv_triangles", f"shape {f.shape} with indices in [0, {len(uv)})", str(ut.shape))


def as_face_varying(mesh: Asset | FaceVaryingMesh, source: str = "<mesh>") -> FaceVaryingMesh:
    """The face-varying arrays of an :class:`Asset` or a :class:`FaceVaryingMesh` (a
    :class:`trimesh.Trimesh` goes through :func:`from_trimesh` first)."""
    if isinstance(mesh, FaceVaryingMesh):
        return mesh
    if isinstance(mesh, Asset):
        return FaceVaryingMesh(mesh.vertices, mesh.triangles, mesh.uv, mesh.uv_triangles)
    raise InputError(source, "mesh", "a facegeo Asset or FaceVaryingMesh (a trimesh.Trimesh: facegeo.export.from_trimesh)",
                     type(mesh).__name__)


def wedges(triangles: np.ndarray, uv_triangles: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct (vertex, UV) corner pairs.

    Returns ``(vertex_of_wedge (W,), uv_of_wedge (W,), wedge_triangles (F, 3))``: one entry per
    distinct pair, sorted by vertex then UV index, and the triangles re-indexed to wedges. Without
    UVs the wedges are the referenced vertices.
    """
    f = np.asarray(triangles, dtype=np.int64)
    if uv_triangles is None:
        used, inverse = np.unique(f.ravel(), return_inverse=True)
        return used, np.full(len(used), -1, dtype=np.int64), inverse.reshape(f.shape)
    t = np.asarray(uv_triangles, dtype=np.int64)
    n_uv = int(t.max()) + 1
    key = f.ravel() * n_uv + t.ravel()
    unique_keys, inverse = np.unique(key, return_inverse=True)
    return unique_keys // n_uv, unique_keys % n_uv, inverse.reshape(f.shape)


def from_trimesh(mesh: Any) -> FaceVaryingMesh:
    """Weld a :class:`trimesh.Trimesh` into face-varying arrays.

    Vertices at exactly the same position become one geometry vertex; ``mesh.visual.uv`` (one UV
    per trimesh vertex, origin bottom-left as trimesh reads OBJ and glTF) becomes the UV layer.
    A mesh without UVs gives ``uv = uv_triangles = None``.
    """
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if len(vertices) == 0 or len(faces) == 0:
        raise InputError("<trimesh>", "mesh", "a mesh with vertices and faces", f"{len(vertices)} vertices, {len(faces)} faces")
    unique, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)  # keep the first-seen vertex order
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    welded = unique[order]
    triangles = rank[inverse.reshape(-1)][faces]
    uv = getattr(getattr(mesh, "visual", None), "uv", None)
    if uv is None or len(uv) != len(vertices):
        return FaceVaryingMesh(welded, triangles)
    return FaceVaryingMesh(welded, triangles, np.asarray(uv, dtype=np.float64), faces)


def to_trimesh(mesh: Asset | FaceVaryingMesh, normals: np.ndarray | None = None, material: Any = None) -> Any:
    """A :class:`trimesh.Trimesh` with one vertex per wedge, UVs in ``visual.uv`` and smooth
    vertex normals (one per geometry vertex, so seams do not show in shading).

    ``mesh`` is an :class:`Asset` (its albedo map, if any, becomes the material's base colour
    texture) or a :class:`FaceVaryingMesh`. ``normals``: (V, 3)
    per geometry vertex; default :func:`facegeo.normals.vertex_normals`. ``process=False`` keeps the order.
    """
    import trimesh
    from trimesh.visual import TextureVisuals

    fv = as_face_varying(mesh)
    if normals is None:
        normals = vertex_normals(fv.vertices, fv.triangles)
    vw, tw, faces = wedges(fv.triangles, fv.uv_triangles)
    if material is None and isinstance(mesh, Asset) and "albedo" in mesh.maps:
        from PIL import Image

        from facegeo.image_files import to_uint

        material = trimesh.visual.material.PBRMaterial(
            name=mesh.name, baseColorTexture=Image.fromarray(to_uint(mesh.maps["albedo"], 8)),
            metallicFactor=0.0)
    out = trimesh.Trimesh(fv.vertices[vw], faces, vertex_normals=np.asarray(normals)[vw], process=False)
    if fv.has_uv:
        out.visual = TextureVisuals(uv=fv.uv[tw], material=material)
    return out
