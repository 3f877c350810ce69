"""Geometry maps: position, normal, MikkTSpace tangent and bitangent sign of a mesh in UV space.

Each map is the barycentric interpolation, over the triangle that covers a texel (or, in the seam
padding, the closest point of the nearest triangle; see :mod:`facegeo.uv.raster`), of per-corner
data:

* ``position`` (S, S, 3) float32, mm, in the frame of the vertices given (model space for
  ``fit.shape_vertices``, camera space for ``fit.vertices``);
* ``normal`` (S, S, 3) float32: the interpolated area-weighted vertex normals
  (:func:`facegeo.normals.vertex_normals`), renormalised;
* ``tangent`` (S, S, 3) float32: the interpolated MikkTSpace corner tangents, renormalised;
* ``bitangent_sign`` (S, S) float32: ±1 (the triangle's corner sign: MikkTSpace gives all corners
  of a triangle the same sign, except where degenerate triangles copy from others; then the sign
  of their sum), with
  bitangent = sign · cross(normal, tangent), the glTF / Blender convention; a tangent-space
  normal n_t (OpenGL convention, +Y = bitangent) maps to n = n_t.x·T + n_t.y·B + n_t.z·N.

Texels without a triangle hold zeros (a zero normal marks them); ``mask`` tells them apart.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facegeo.errors import InputError
from facegeo.uv.raster import UVRaster, rasterize_uv
from facegeo.normals import vertex_normals
from facegeo.uv.tangents import mesh_tangents

__all__ = ["GeometryMaps", "geometry_maps"]


@dataclass(frozen=True, eq=False)
class GeometryMaps:
    """Geometry of a mesh in UV space (see the module docstring for the conventions).

    Attributes:
        position: (S, S, 3) float32, mm.
        normal: (S, S, 3) float32 unit vectors (zeros outside ``mask``).
        tangent: (S, S, 3) float32 unit MikkTSpace tangents, or None when not computed.
        bitangent_sign: (S, S) float32 ±1 (0 outside ``mask``), or None with the tangent.
        mask: (S, S) bool, texels that have a triangle (inside or seam padding).
        raster: the :class:`UVRaster` used.
        texel: the same data per texel of the raster ((N, 3) / (N,) float32 arrays named
            position, normal, tangent, sign), in ``raster.texels`` order.
    """

    position: np.ndarray
    normal: np.ndarray
    tangent: np.ndarray | None
    bitangent_sign: np.ndarray | None
    mask: np.ndarray
    raster: UVRaster
    texel: dict = field(default_factory=dict, repr=False)

    @property
    def size(self) -> int:
        """S."""
        return self.raster.size

    def bitangent(self) -> np.ndarray:
        """(S, S, 3) float32: sign · cross(normal, tangent)."""
        if self.tangent is None or self.bitangent_sign is None:
            raise ValueError("these geometry maps were computed without tangents")
        return (self.bitangent_sign[..., None] * np.cross(self.normal, self.tangent)).astype(np.float32)


def geometry_maps(vertices: np.ndarray, model, raster: UVRaster | None = None, *, size: int = 1024,
                  normals: np.ndarray | None = None, tangents: bool = True) -> GeometryMaps:
    """Position, normal, MikkTSpace tangent and bitangent-sign maps of a mesh.

    Args:
        vertices: (V, 3) vertex positions in mm (any frame; the maps are in that frame).
        model: the :class:`facegeo.MorphableModel` giving ``triangles``, ``uv`` and
            ``uv_triangles`` (any object with those attributes).
        raster: the layout's :class:`UVRaster`; default ``rasterize_uv(model, size=size)``
            (cached).
        size: S, used when ``raster`` is None.
        normals: (V, 3) unit vertex normals; default the area-weighted ones
            (:func:`facegeo.normals.vertex_normals`). Exporters must write the same normals.
        tangents: also compute the MikkTSpace tangent and sign maps (about half the time).
    Returns:
        :class:`GeometryMaps`, all float32 (S, S, ·).
    Raises:
        InputError: vertices of the wrong shape or with NaN/inf values, or a raster made for a
            different number of triangles.
    """
    triangles = np.asarray(model.triangles, dtype=np.int64)
    if raster is None:
        raster = rasterize_uv(model, size=size)
    v = _check_vertices(vertices, triangles, "vertices")
    if raster.n_triangles != triangles.shape[0]:
        raise InputError("<argument>", "raster", f"a UV raster of this model's {triangles.shape[0]} triangles",
                         f"one of {raster.n_triangles}")
    if normals is None:
        n = vertex_normals(v, triangles).astype(np.float32)
    else:
        n = _check_vertices(normals, triangles, "normals")
    geo = texel_geometry(v, n, model, raster, tangents=tangents)
    S = raster.size
    mask = raster.mask
    position = raster.scatter(geo["position"])
    normal = raster.scatter(geo["normal"])
    tangent = raster.scatter(geo["tangent"]) if tangents else None
    sign = raster.scatter(geo["sign"]) if tangents else None
    assert position.shape == (S, S, 3)
    return GeometryMaps(position, normal, tangent, sign, mask, raster, geo)


def texel_geometry(vertices: np.ndarray, normals: np.ndarray, model, raster: UVRaster,
                   tangents: bool = True) -> dict[str, np.ndarray]:
    """Per-texel geometry for the raster's N texels: ``position`` (N, 3), ``normal`` (N, 3) and,
    with ``tangents``, ``tangent`` (N, 3) and ``sign`` (N,); all float32."""
    triangles = np.asarray(model.triangles, dtype=np.int64)
    tri = raster.texel_triangle
    b = raster.texel_barycentric
    corner_pos = vertices[triangles]  # (F, 3, 3)
    out = {"position": _interpolate(corner_pos, tri, b)}
    out["normal"] = _normalise(_interpolate(normals[triangles], tri, b))
    if tangents:
        corner = mesh_tangents(vertices, triangles, model.uv, model.uv_triangles, normals)  # (F, 3, 4)
        out["tangent"] = _normalise(_interpolate(corner[..., :3], tri, b))
        tri_sign = np.where(corner[..., 3].sum(axis=1) >= 0, np.float32(1.0), np.float32(-1.0))
        out["sign"] = tri_sign[tri]
    return out


def _interpolate(corner_values: np.ndarray, tri: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("nk,nkc->nc", b, np.asarray(corner_values, dtype=np.float32)[tri])


def _normalise(v: np.ndarray) -> np.ndarray:
    length = np.sqrt(np.einsum("ij,ij->i", v, v))[:, None]
    return np.where(length > 1e-20, v / np.maximum(length, 1e-30), 0.0).astype(np.float32)


def _check_vertices(vertices: np.ndarray, triangles: np.ndarray, name: str) -> np.ndarray:
    v = np.asarray(vertices)
    need = int(triangles.max()) + 1 if triangles.size else 0
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < need or v.dtype.kind not in "fiu":
        raise InputError("<array>", name, f"a (V, 3) array of numbers with V ≥ {need}", f"{v.dtype} array of shape {v.shape}")
    v = v.astype(np.float32)
    if not np.all(np.isfinite(v)):
        raise InputError("<array>", name, "finite values", f"{int(np.sum(~np.isfinite(v)))} NaN/inf values")
    return v
