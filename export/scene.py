"""The geometry and material inputs that a written scene carries (shared by the USD and glTF writers).

:func:`scene_contents` subdivides the asset to the requested level, bakes its displacement into
the geometry (``displacement="bake"``) or leaves it for a material input (``"texture"``, USD
only), computes smooth vertex normals of the final geometry, and resolves which maps become
textures and which factors (:func:`facegeo.export.textures.material_inputs`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from facegeo.asset import Asset
from facegeo.errors import InputError
from facegeo.export.displacement import bake_displacement
from facegeo.normals import vertex_normals
from facegeo.export.facevarying import FaceVaryingMesh
from facegeo.export.subdivision import subdivide_arrays
from facegeo.export.textures import MaterialInput, material_inputs

__all__ = ["SceneContents", "scene_contents", "DISPLACEMENT_MODES"]

#: ``displacement=`` values: bake into the geometry, or a material input (USD only).
DISPLACEMENT_MODES = ("bake", "texture")


@dataclass
class SceneContents:
    """The mesh to write (float64 mm, face-varying UVs, (V, 3) unit normals) and the material
    inputs (``inputs`` never holds a baked displacement)."""

    mesh: FaceVaryingMesh
    normals: np.ndarray
    inputs: dict[str, MaterialInput]
    level: int
    displacement: str

    @property
    def textured(self) -> bool:
        """Whether any input is a texture (then the mesh needs its UVs)."""
        return any(i.is_texture for i in self.inputs.values())


def scene_contents(asset: Asset, *, level: int = 0, displacement: str = "bake", maps: Iterable[str] | None = None,
                   uv_interpolation: str = "surface") -> SceneContents:
    """Subdivide, bake (or not) and resolve the material of ``asset`` for a writer."""
    if not isinstance(asset, Asset):
        raise InputError("<export>", "asset", "a facegeo.asset.Asset", type(asset).__name__)
    asset.validate("<export>")  # again: the maps may have been changed since construction
    if displacement not in DISPLACEMENT_MODES:
        raise InputError("<export>", "displacement", f"one of {', '.join(DISPLACEMENT_MODES)}", repr(displacement))
    inputs = material_inputs(asset, maps)
    v, f, uv, ut = subdivide_arrays(asset.vertices, asset.triangles, asset.uv, asset.uv_triangles, level, uv_interpolation=uv_interpolation)
    mesh = FaceVaryingMesh(v, f, uv, ut)
    disp = inputs.get("displacement")
    if disp is not None and displacement == "bake":
        mesh = bake_displacement(mesh, disp.texture if disp.is_texture else float(disp.value), 1.0)
        del inputs["displacement"]
    normals = vertex_normals(mesh.vertices, mesh.triangles)
    return SceneContents(mesh, normals, inputs, int(level), displacement)
