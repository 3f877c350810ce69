"""The geometry and material inputs that a written scene carries (shared by the USD and glTF writers).

:func:`scene_contents` subdivides the asset to the requested level, bakes its displacement into
the geometry (``displacement="bake"``) or leaves it for a material input (``"texture"``, USD
only), computes smooth vertex normals of the final geometry, and resolves which maps become
textures and which factors (:func:`facegeo.export.textures.material_inputs`).

With ``blendshapes`` (a naming of :data:`facegeo.arkit.BLENDSHAPE_NAMINGS`) and an asset
that carries :class:`facegeo.blendshapes.Blendshapes`, the mesh written is the **neutral** one
(identity only, subdivided and displaced the same way) and ``targets`` holds the morph targets
that pose it (:func:`facegeo.export.morph_targets.surface_targets`); the writers set the targets'
weights to the fitted ones, so the file still shows the photo's expression.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

from facegeo.asset import Asset
from facegeo.errors import InputError
from facegeo.export.displacement import bake_displacement
from facegeo.normals import vertex_normals
from facegeo.export.facevarying import FaceVaryingMesh
from facegeo.arkit import target_naming
from facegeo.export.morph_targets import SurfaceTargets, surface_targets
from facegeo.export.subdivision import subdivide_with_operators
from facegeo.export.textures import MaterialInput, material_inputs

__all__ = ["SceneContents", "SceneGeometry", "scene_contents", "scene_geometries", "scene_surfaces", "DISPLACEMENT_MODES"]

#: ``displacement=`` values: bake into the geometry, or a material input (USD only).
DISPLACEMENT_MODES = ("bake", "texture")


@dataclass
class SceneContents:
    """The mesh to write (float64 mm, face-varying UVs, (V, 3) unit normals) and the material
    inputs (``inputs`` never holds a baked displacement); ``targets``: the morph targets of the
    mesh (then the neutral mesh), or None; ``derived``: what a writer made of this geometry alone,
    by its own key (shared with the :class:`SceneGeometry` it came from)."""

    mesh: FaceVaryingMesh
    normals: np.ndarray
    inputs: dict[str, MaterialInput]
    level: int
    displacement: str
    targets: SurfaceTargets | None = None
    derived: dict[Any, Any] = field(default_factory=dict, compare=False, repr=False)

    @property
    def textured(self) -> bool:
        """Whether any input is a texture (then the mesh needs its UVs)."""
        return any(i.is_texture for i in self.inputs.values())


@dataclass(frozen=True)
class SceneGeometry:
    """What a surface's scene needs of its geometry alone, without its maps (nothing baked):
    ``mesh`` (float64 mm, subdivided to ``level``), ``normals`` (V, 3) unit, ``targets`` as in
    :class:`SceneContents`; ``uv_interpolation`` and ``blendshapes`` as they were made with;
    ``derived``: what a writer made of it before the maps existed
    (:func:`facegeo.export.gltf.prepare_surface_arrays`), which the contents made from it share."""

    mesh: FaceVaryingMesh
    normals: np.ndarray
    targets: SurfaceTargets | None
    level: int
    uv_interpolation: str
    blendshapes: str | None
    derived: dict[Any, Any] = field(default_factory=dict, compare=False, repr=False)


def _geometry(asset: Asset, level: int, uv_interpolation: str, blendshapes: str | None,
              displacement: np.ndarray | float | None) -> SceneGeometry:
    """Subdivide ``asset`` (its neutral mesh when it has blendshapes and ``blendshapes`` names
    them), bake ``displacement`` (mm: an (H, W) map or a constant) into it when given, and make
    its normals and morph targets."""
    shapes = asset.blendshapes if blendshapes is not None else None
    naming = target_naming(shapes.names, blendshapes) if shapes is not None else None
    coarse = asset.neutral_vertices() if shapes is not None else asset.vertices
    v, f, uv, ut, operators = subdivide_with_operators(coarse, asset.triangles, asset.uv, asset.uv_triangles, level,
                                                       uv_interpolation=uv_interpolation)
    mesh = FaceVaryingMesh(v, f, uv, ut)
    if displacement is not None:
        mesh = bake_displacement(mesh, displacement, 1.0)
    normals = vertex_normals(mesh.vertices, mesh.triangles)
    targets = None
    if shapes is not None and naming is not None:
        targets = surface_targets(shapes, coarse, asset.triangles, naming, operators)
    return SceneGeometry(mesh, normals, targets, int(level), uv_interpolation, blendshapes)


def scene_geometries(asset: Asset, *, level: int = 0, uv_interpolation: str = "surface",
                     blendshapes: str | None = None) -> list[SceneGeometry]:
    """The :class:`SceneGeometry` of the skin (at ``level``) and of each part (level 0), in
    :func:`scene_surfaces`' order: what a scene needs before the maps exist (``facegeo
    reconstruct`` makes them while the texture stages run). Valid for a scene that bakes no
    displacement map into the skin."""
    if not isinstance(asset, Asset):
        raise InputError("<export>", "asset", "a facegeo.asset.Asset", type(asset).__name__)
    return [_geometry(asset, level, uv_interpolation, blendshapes, None)] + [
        _geometry(part, 0, "surface", blendshapes, None) for part in asset.parts]


def scene_contents(asset: Asset, *, level: int = 0, displacement: str = "bake", maps: Iterable[str] | None = None,
                   uv_interpolation: str = "surface", blendshapes: str | None = None,
                   geometry: SceneGeometry | None = None) -> SceneContents:
    """Subdivide, bake (or not) and resolve the material of ``asset`` for a writer; with
    ``blendshapes`` ("arkit" or "ict") and an asset that has them, the neutral mesh and its
    morph targets under that naming (None: the posed mesh, no targets). ``geometry``: this
    surface's :func:`scene_geometries` entry if already made with the same options (used when no
    displacement is baked)."""
    if not isinstance(asset, Asset):
        raise InputError("<export>", "asset", "a facegeo.asset.Asset", type(asset).__name__)
    asset.validate("<export>")  # again: the maps may have been changed since construction
    if displacement not in DISPLACEMENT_MODES:
        raise InputError("<export>", "displacement", f"one of {', '.join(DISPLACEMENT_MODES)}", repr(displacement))
    inputs = material_inputs(asset, maps)
    disp = inputs.pop("displacement", None) if displacement == "bake" else None
    bake = None if disp is None else (disp.texture if disp.is_texture else float(disp.value))
    if geometry is not None and (bake is not None or (geometry.level, geometry.uv_interpolation, geometry.blendshapes)
                                 != (int(level), uv_interpolation, blendshapes)):
        raise InputError("<export>", "geometry", f"the scene geometry of level {level}, {uv_interpolation} UVs, "
                         f"blendshapes {blendshapes} and nothing baked",
                         f"level {geometry.level}, {geometry.uv_interpolation} UVs, blendshapes {geometry.blendshapes}"
                         + (", a displacement to bake" if bake is not None else ""))
    made = geometry or _geometry(asset, level, uv_interpolation, blendshapes, bake)
    return SceneContents(made.mesh, made.normals, inputs, int(level), displacement, made.targets, made.derived)


def scene_surfaces(asset: Asset, *, level: int = 0, displacement: str = "bake", maps: Iterable[str] | None = None,
                   uv_interpolation: str = "surface", blendshapes: str | None = None,
                   geometries: list[SceneGeometry] | None = None) -> list[tuple[str, SceneContents]]:
    """``(name, contents)`` of every surface a scene of ``asset`` holds: the skin (at ``level``,
    with ``maps``, ``displacement``) and each part (level 0, its own material). The writers take
    them from here; computing them once serves every format that bakes the displacement
    (:func:`facegeo.export.writers.export_scenes`). ``geometries``: the asset's
    :func:`scene_geometries` with the same options, if already made."""
    skin, parts = (None, [None] * len(asset.parts)) if geometries is None else (geometries[0], geometries[1:])
    if len(parts) != len(asset.parts):
        raise InputError("<export>", "geometries", f"{len(asset.parts) + 1} surfaces (the skin and its parts)", str(len(geometries or ())))
    surfaces = [(asset.name, scene_contents(asset, level=level, displacement=displacement, maps=maps,
                                            uv_interpolation=uv_interpolation, blendshapes=blendshapes, geometry=skin))]
    return surfaces + [(part.name, scene_contents(part, blendshapes=blendshapes, geometry=geometry))
                       for part, geometry in zip(asset.parts, parts)]
