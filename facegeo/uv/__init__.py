"""UV space: the rasteriser, geometry maps (position, normal, MikkTSpace tangent), the
occlusion-aware unwrap of a photo (T_inc, M_vis) and the z-buffer renderer that inverts it.

Conventions (DESIGN.md, "Conventions"): mm; camera space looks down −Z; UV [0, 1]² with the origin bottom-left,
maps stored row 0 = top (texel (i, j) centre at u = (j + 0.5)/S, v = 1 − (i + 0.5)/S); image
pixels continuous with the origin at the top-left corner (centres at +0.5). In code, these
conventions live in :mod:`facegeo.uv.texels` (uv ↔ texel, bilinear lookups).

    raster = rasterize_uv(model, size=1024)              # cached per layout, size and padding
    maps = geometry_maps(fit.shape_vertices, model, raster)   # position/normal/tangent/sign
    T_inc, M_vis = unwrap(photo.image, fit, model, 1024)  # sRGB float32 texture, visibility
    view = render(fit.vertices, model, fit.camera, texture=T_inc)
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from facegeo.lazy_exports import lazy_exports

# Names are imported lazily (like ``facegeo``'s), so ``facegeo --help`` and the CLI's parser do not
# pay for torch, OpenCV and SciPy.
_EXPORTS = {
    "UVRaster": "facegeo.uv.raster",
    "rasterize_uv": "facegeo.uv.raster",
    "default_padding": "facegeo.uv.raster",
    "clear_raster_cache": "facegeo.uv.raster",
    "GeometryMaps": "facegeo.uv.maps",
    "geometry_maps": "facegeo.uv.maps",
    "vertex_normals": "facegeo.normals",
    "mikktspace_tangents": "facegeo.uv.tangents",
    "mesh_tangents": "facegeo.uv.tangents",
    "unwrap": "facegeo.uv.unwrapping",
    "unwrap_details": "facegeo.uv.unwrapping",
    "Unwrapped": "facegeo.uv.unwrapping",
    "FACING_RAMP": "facegeo.uv.unwrapping",
    "Rendering": "facegeo.uv.renderer",
    "render": "facegeo.uv.renderer",
    "rasterize_mesh": "facegeo.uv.renderer",
    "light_visibility": "facegeo.uv.renderer",
    "sky_visibility": "facegeo.uv.renderer",
}

__all__ = list(_EXPORTS)

if TYPE_CHECKING:
    from facegeo.uv.maps import GeometryMaps, geometry_maps
    from facegeo.uv.raster import UVRaster, clear_raster_cache, default_padding, rasterize_uv
    from facegeo.uv.renderer import Rendering, light_visibility, rasterize_mesh, render, sky_visibility
    from facegeo.normals import vertex_normals
    from facegeo.uv.tangents import mesh_tangents, mikktspace_tangents
    from facegeo.uv.unwrapping import FACING_RAMP, Unwrapped, unwrap, unwrap_details


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
