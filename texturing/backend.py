"""The texture-backend interface and the context the geometry stage hands to it.

A backend turns the incomplete, shaded photo texture ``T_inc`` in UV space into PBR maps in four
steps: ``inpaint`` → ``homogenise`` → ``materials`` → ``upscale``. The default backend is
weight-free (:mod:`facegeo.texturing.default`); the diffusion backend is an adapter over
a DiT and plugs into the same protocol. :class:`TextureBackend` declares everything the pipeline
(:func:`facegeo.pipeline.reconstruct_with_fit`) uses of a backend: the four stages, ``name``,
``report`` (copied into ``fit.json``'s ``texture_report``) and ``constants`` (the values of the
maps not computed). :data:`facegeo.texturing.registry.BACKENDS` names the backends by name.

Array conventions: UV maps are image-style (row 0 = top, v = 1 − (row + 0.5)/S), float32.
Colour textures (``T_inc``, ``T_full``, ``T_hom``, the ``albedo`` map) are **sRGB-encoded** in
[0, 1]; shading is computed in linear RGB.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from types import MappingProxyType
from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = ["TextureContext", "TextureBackend", "SurfaceOperators", "SKIN_CONSTANTS"]

#: Roughness and specular level of generic skin (away from the oily T-zone, the lips and brows):
#: what a backend's ``constants`` give the maps it was not asked to compute (the exporters write
#: them as factors), the default backend's prior where no facial region says otherwise, and the
#: relit preview's value for a surface with neither map nor constant. The one definition.
SKIN_CONSTANTS: Mapping[str, float] = MappingProxyType({"roughness": 0.55, "specular": 0.45})


@dataclass(eq=False)
class SurfaceOperators:
    """Linear maps between the mesh's vertices and the texels of the layout, so that values can be
    smoothed or extrapolated on the surface (continuous across UV seams) instead of in UV.

    texels: (N,) int64 flat indices ``row * S + col`` of the texels that have a triangle.
    interpolation: (N, V) scipy.sparse CSR, the barycentric weights of each texel's triangle
        corners (rows sum to 1): texel values = interpolation @ vertex values.
    laplacian: (V, V) scipy.sparse CSR, the graph Laplacian of the mesh's edges (degree − adjacency).
    """

    texels: np.ndarray
    interpolation: Any
    laplacian: Any

    def to_texels(self, per_vertex: np.ndarray, size: int) -> np.ndarray:
        """(V[, C]) vertex values -> (S, S[, C]) float32 map (0 where no triangle)."""
        values = np.asarray(self.interpolation @ per_vertex, np.float32)
        out = np.zeros((size * size, *values.shape[1:]), np.float32)
        out[self.texels] = values
        return out.reshape(size, size, *values.shape[1:])

    def to_vertices(self, texture: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted average of an (S, S[, C]) map around each vertex (the transpose of the
        interpolation): ``(values (V[, C]), weight (V,))``, the weight being the vertex's mean
        texel weight (0 where no texel with weight > 0 touches it)."""
        size = texture.shape[0]
        w = weight.reshape(-1)[self.texels].astype(np.float64)
        t = texture.reshape(size * size, -1)[self.texels].astype(np.float64)
        num = self.interpolation.T @ (t * w[:, None])
        den = np.asarray(self.interpolation.T @ w).ravel()
        cnt = np.asarray(self.interpolation.sum(axis=0)).ravel()
        values = num / np.maximum(den, 1e-12)[:, None]
        return (values if texture.ndim == 3 else values[:, 0]), den / np.maximum(cnt, 1e-12)


@dataclass(eq=False)
class TextureContext:
    """What the geometry stage knows, in UV space at size S × S.

    coverage: (S, S) bool, texels inside the UV layout.
    position: (S, S, 3) float32 model-space position in mm (0 outside).
    normal_camera: (S, S, 3) float32 unit geometric normals rotated into camera space (the frame
        of the fitted SH lighting); 0 outside.
    texel_size_mm: (S, S, 2) float32 length in mm of one texel step along +u (columns) and +v
        (rows upwards) on the surface.
    gamma: (3, 9) float32 fitted SH coefficients (Deep3D convention, :mod:`facegeo.lighting`).
    mean_texture: (S, S, 3) float32 the model's mean (or fitted) albedo in UV, sRGB-encoded.
    mirror: (S, S, 2) int32 (row, col) of each texel's left/right mirror texel on the face, or
        (−1, −1) where it has none.
    regions: name -> (S, S) float32 soft masks in [0, 1] (``forehead``, ``nose``, ``cheeks``,
        ``lips``, ``brows``, ``chin``, ``eyes``); the priors of the material estimate.
    skin: (S, S) float32 in [0, 1], where the texture is skin (no eyes, brows, lips, hair).
    surface: :class:`SurfaceOperators` of the mesh, or None (then backends work in UV alone).
    white_reference: (3,) float64 mean linear RGB of the photo's white references (sclera,
        teeth; :func:`facegeo.skin_mask.white_reference`), or None: evidence of the light's colour.
    position_camera: (S, S, 3) float32 texel positions on the posed mesh in camera space, mm (0
        outside), or None; with ``vertices_camera`` and ``triangles`` the evidence of cast
        shadows (a shadow map of the fitted mesh, :func:`facegeo.uv.light_visibility`).
    vertices_camera: (V, 3) float32 the posed mesh's vertices in camera space, mm (``fit.vertices``),
        or None.
    triangles: (F, 3) int64 the mesh's triangles (vertex indices), or None.
    """

    coverage: np.ndarray
    position: np.ndarray
    normal_camera: np.ndarray
    texel_size_mm: np.ndarray
    gamma: np.ndarray
    mean_texture: np.ndarray
    mirror: np.ndarray
    regions: dict[str, np.ndarray] = field(default_factory=dict)
    skin: np.ndarray | None = None
    surface: SurfaceOperators | None = None
    white_reference: np.ndarray | None = None
    position_camera: np.ndarray | None = None
    vertices_camera: np.ndarray | None = None
    triangles: np.ndarray | None = None

    @property
    def size(self) -> int:
        """S, the texture size in texels."""
        return int(self.coverage.shape[0])

    @cached_property
    def median_texel_mm(self) -> float:
        """The median of ``texel_size_mm`` over the covered texels, both directions, in mm
        (computed on first use; the context's arrays are not to be changed after it is built)."""
        return float(np.median(self.texel_size_mm[self.coverage]))


@runtime_checkable
class TextureBackend(Protocol):
    """The four texture stages, and what the pipeline reads besides. Shapes: S × S texels;
    colour maps sRGB in [0, 1], float32.

    Attributes:
        name: recorded as ``asset.metadata["backend"]``.
        report: JSON-ready statistics or settings of the last calls (the backend fills it as it
            runs); the pipeline copies it into ``asset.metadata["texture_report"]`` and
            ``fit.json``'s ``texture_report``.
        constants: map name -> value for the maps the backend may be asked not to compute
            (``roughness`` and ``specular``; :data:`SKIN_CONSTANTS` for both backends); the
            pipeline puts those not computed into ``Asset.constants``.
    """

    name: str
    report: dict[str, Any]
    constants: Mapping[str, float]

    def inpaint(self, T_inc: np.ndarray, M_vis: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """Complete the photo texture: ``T_inc`` (S, S, 3) sRGB, ``M_vis`` (S, S) visibility in
        [0, 1] -> ``T_full`` (S, S, 3) sRGB with every covered texel filled."""
        ...

    def homogenise(self, T_full: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """Remove the photo's lighting: (S, S, 3) sRGB -> ``T_hom`` (S, S, 3) sRGB, the texture
        under uniform white light (the diffuse albedo up to a global scale)."""
        ...

    def materials(self, T_hom: np.ndarray, ctx: TextureContext, maps: frozenset[str] | set[str] = ...) -> dict[str, np.ndarray]:
        """PBR maps from the homogenised texture, only those named in ``maps`` (see
        :mod:`facegeo.asset` for each map's shape, range and unit)."""
        ...

    def upscale(self, map_: np.ndarray, factor: int) -> np.ndarray:
        """(S, S[, C]) -> (factor·S, factor·S[, C]), same dtype and encoding."""
        ...
