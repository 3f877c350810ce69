"""glTF 2.0 binary (``.glb``) export with metallic-roughness PBR and ``KHR_materials_specular``.

Conventions: glTF is in metres (+Y up, the asset facing +Z), so points are scaled by 0.001; its
texture origin is top-left, so ``TEXCOORD_0 = (u, 1 − v)``. Images keep their rows (row 0 = top,
as glTF expects). glTF has no displacement: it is always baked into the geometry.

One vertex per (vertex, UV) wedge; ``NORMAL`` is the smooth area-weighted normal of the geometry
vertex (the same on both sides of a seam). The material:

* ``pbrMetallicRoughness``: ``baseColorTexture`` (albedo, 8-bit sRGB PNG) or
  ``baseColorFactor`` (the albedo constant, linearised); ``metallicFactor = 0``; roughness as a
  ``metallicRoughnessTexture`` (G = roughness, B = metallic = 0, R = 1 so that engines reading
  an occlusion-roughness-metallic texture see no occlusion) with ``roughnessFactor = 1``, or as
  ``roughnessFactor`` (the constant, 0.5 when the asset has none; glTF's own default is 1);
* ``normalTexture`` (8-bit linear, OpenGL +Y as glTF expects) with ``TANGENT`` attributes: the
  MikkTSpace tangents of the written mesh and its written normals, computed by
  :func:`facegeo.uv.tangents.mesh_tangents` (the implementation the texture stage bakes normal
  maps with) in the Asset's UV space (v up): w = +1 where the UV winding is counter-clockwise, so
  B = w·(N × T) points to +v = up in the image, which is what glTF and the normal map's green
  channel mean. A vertex whose corners get different tangents is split;
* specular (F0 = 0.08 × specular, F90 = 1): ``KHR_materials_specular`` as its specification's
  "materials with reflectance parameter" conversion: ``specularColorFactor = [2, 2, 2]`` and
  ``specularColorTexture`` = the specular map, sRGB-encoded (the extension reads that texture as
  sRGB; its F0 is 0.04 × colour); a constant s is ``specularColorFactor = [2s, 2s, 2s]``.
  Without a specular input the extension is not written (glTF's default F0 is 0.04 = 0.08 × 0.5).

Parts (``asset.parts``) follow the skin as their own meshes, nodes and materials (``<part>``,
``<part>_material``, textures named ``<part>_<map>``), all nodes in the one scene.

Blendshapes (``blendshapes="arkit"``, the default, or ``"ict"``; issue 28): each mesh with
blendshapes is written neutral with one morph target per name
(:mod:`facegeo.export.morph_targets`): ``POSITION`` displacements as normalized shorts (metres,
1/32767 m steps) and ``NORMAL`` changes as normalized bytes, both as sparse accessors, which needs
the ``KHR_mesh_quantization`` extension (listed as required); ``mesh.weights`` are the fitted
weights (the file shows the photo's expression), ``mesh.extras.targetNames`` the names, the same
on every mesh; ``asset.extras`` records the naming (``blendshapeNames``) and what the targets lack
(``blendshapeNotes``: ARKit's ``tongueOut``, merged halves that differed).

With an ``animation`` (a Live Link Face take) the scene is a ``head`` node holding every mesh
node, and the eyeballs become two meshes on ``eye_left`` / ``eye_right`` nodes placed at the
eyes' centres (:mod:`facegeo.export.animation`); one animation keys the take: a ``weights``
channel per mesh with targets and ``rotation`` channels for the head and the eyes, linear, at the
take's times.

``TEXCOORD_0`` is written only when a texture uses it, ``TANGENT`` only with a normal texture.
Textures are clamped to the edge and mip-mapped. :func:`validate_glb` runs the Khronos
glTF-Validator (npm ``gltf-validator``) when node and the package are available.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from facegeo.arkit import ArkitTake
from facegeo.asset import SPECULAR_F0_SCALE, Asset
from facegeo.colour import linear_to_srgb, srgb_to_linear
from facegeo.errors import InputError
from facegeo.export.animation import EYE_NAMES, HEAD_NAME, FaceRig, face_rig, rotations, target_weights
from facegeo.export.facevarying import wedges
from facegeo.export.morph_targets import NORMAL_TARGET_MIN, SurfaceTargets
from facegeo.export.scene import SceneContents, SceneGeometry, scene_contents, scene_surfaces
from facegeo.export.textures import DEFAULT_ROUGHNESS, TextureFiles, material_inputs
from facegeo.image_files import png_bytes, to_uint
from facegeo.staged_output import atomic_write_bytes

__all__ = ["write_glb", "glb_bytes", "surface_arrays", "prepare_surface_arrays", "validate_glb", "find_gltf_validator", "GltfValidatorMissing", "VALIDATOR_ENV_VAR",
           "WRITER_LIBRARIES"]

#: The libraries :func:`write_glb` imports when it runs (kept out of ``import facegeo``); a caller
#: that writes on threads imports them first (:func:`facegeo.export.writers.scene_writers`).
WRITER_LIBRARIES = ("pygltflib",)

#: Environment variable naming the ``gltf-validator`` npm package folder (the one holding
#: ``package.json``) or a ``node_modules`` folder that contains it.
VALIDATOR_ENV_VAR = "FACEGEO_GLTF_VALIDATOR"

_ARRAY_BUFFER = 34962
_ELEMENT_ARRAY_BUFFER = 34963
_FLOAT = 5126
_BYTE = 5120
_SHORT = 5122
_UNSIGNED_SHORT = 5123
_UNSIGNED_INT = 5125


def write_glb(asset: Asset, path: str | os.PathLike[str], *, level: int = 0, maps: Iterable[str] | None = None,
              uv_interpolation: str = "surface", blendshapes: str | None = "arkit", animation: ArkitTake | None = None,
              surfaces: list[tuple[str, SceneContents]] | None = None, texture_files: TextureFiles | None = None) -> Path:
    """Write ``asset`` as a ``.glb`` (atomically). ``level``: Loop subdivision levels before
    baking the displacement; ``maps``: the map names to carry (default: all the asset has);
    ``blendshapes``: the morph targets' names, "arkit" or "ict", or None to leave them out;
    ``animation``: a take to animate the face with; ``surfaces``: the asset's
    :func:`facegeo.export.scene.scene_surfaces` with these options, if already computed (shared
    with another format); ``texture_files``: the maps' PNG files shared with other outputs
    (default: made here). Returns the path.

    Raises:
        InputError: the suffix is not .glb, bad options, or a map asked for that the asset lacks.
    """
    target = Path(path)
    if target.suffix.lower() != ".glb":
        raise InputError(target, "file name", "a .glb suffix (glTF 2.0 binary)", target.suffix or "none")
    data = glb_bytes(asset, level=level, maps=maps, uv_interpolation=uv_interpolation, blendshapes=blendshapes, animation=animation,
                     surfaces=surfaces, texture_files=texture_files)
    target.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(target, data)
    return target


def glb_bytes(asset: Asset, *, level: int = 0, maps: Iterable[str] | None = None, uv_interpolation: str = "surface",
              blendshapes: str | None = "arkit", animation: ArkitTake | None = None,
              surfaces: list[tuple[str, SceneContents]] | None = None, texture_files: TextureFiles | None = None) -> bytes:
    """The ``.glb`` file of ``asset`` as bytes (see :func:`write_glb`): the skin is mesh, node
    and material 0; each part follows as its own mesh, node and material (named after it).
    ``blendshapes``: the targets' naming ("arkit", "ict") or None for none (module docstring);
    ``animation``: a Live Link Face take to animate the face with (needs ``blendshapes``);
    ``texture_files``: the maps' PNG files shared with other outputs (default: made here)."""
    import pygltflib as gl

    if animation is not None and blendshapes is None:
        raise InputError("<export>", "blendshapes", "a naming (arkit or ict) to animate the face with", "none")
    if surfaces is None:
        surfaces = scene_surfaces(asset, level=level, maps=maps, uv_interpolation=uv_interpolation, blendshapes=blendshapes)
    files = TextureFiles() if texture_files is None else texture_files
    rig = face_rig(asset) if animation is not None else None
    if rig is not None:  # the eyeballs become the two eyes
        eyes = [(eye.name, scene_contents(eye, blendshapes=blendshapes)) for eye in rig.eyes]
        surfaces = [s for name, c in surfaces for s in (eyes if name == rig.eyeballs else [(name, c)])]

    blob = bytearray()
    doc = gl.GLTF2(asset=gl.Asset(version="2.0", generator="facegeo"))
    doc.scene = 0
    extensions: list[str] = []

    def view(data: bytes, target: int | None = None) -> int:
        while len(blob) % 4:
            blob.append(0)
        doc.bufferViews.append(gl.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=target))
        blob.extend(data)
        return len(doc.bufferViews) - 1

    def accessor(array: np.ndarray, kind: str, component: int, target: int | None, bounds: bool = False) -> int:
        array = np.ascontiguousarray(array)
        index = view(array.tobytes(), target)
        acc = gl.Accessor(bufferView=index, componentType=component, count=len(array), type=kind)
        if bounds:
            flat = array.reshape(len(array), -1)
            acc.min = [float(x) for x in flat.min(axis=0)]
            acc.max = [float(x) for x in flat.max(axis=0)]
        doc.accessors.append(acc)
        return len(doc.accessors) - 1

    def sparse_accessors(count: int, items: list[tuple[np.ndarray, np.ndarray, int]]) -> list[int]:
        """Normalized VEC3 accessors of ``count`` zeros with ``values`` (n, 3) at ``indices``
        (ascending), one per ``(indices, values, componentType)`` item; all the items' indices
        share one buffer view and all their values another. Bounds are the stored integers
        (zeros included); an item without values is an accessor without a buffer view (zeros)."""
        index_type = np.uint16 if count <= 65535 else np.uint32
        index_bytes, value_bytes = bytearray(), bytearray()
        placed = []
        for indices, values, _ in items:
            placed.append((len(index_bytes), len(value_bytes)))
            index_bytes.extend(indices.astype(index_type).tobytes())
            value_bytes.extend(np.ascontiguousarray(values).tobytes())
            index_bytes.extend(b"\0" * (-len(index_bytes) % 4))
            value_bytes.extend(b"\0" * (-len(value_bytes) % 4))
        index_view = view(bytes(index_bytes)) if index_bytes else None
        value_view = view(bytes(value_bytes)) if value_bytes else None
        lows, highs = _bounds([values for _, values, _ in items])
        out = []
        for (indices, values, component), (index_offset, value_offset), low, high in zip(items, placed, lows, highs):
            acc = gl.Accessor(componentType=component, normalized=True, count=count, type="VEC3", byteOffset=None,
                              min=[float(x) for x in low], max=[float(x) for x in high])
            if len(indices):
                acc.sparse = gl.Sparse(
                    count=len(indices),
                    indices=gl.AccessorSparseIndices(bufferView=index_view, byteOffset=index_offset,
                                                     componentType=_UNSIGNED_SHORT if index_type is np.uint16 else _UNSIGNED_INT),
                    values=gl.AccessorSparseValues(bufferView=value_view, byteOffset=value_offset))
            doc.accessors.append(acc)
            out.append(len(doc.accessors) - 1)
        return out

    def texture(name: str, png: bytes) -> int:
        if not doc.samplers:
            doc.samplers.append(gl.Sampler(magFilter=9729, minFilter=9987, wrapS=33071, wrapT=33071))
        doc.images.append(gl.Image(bufferView=view(png), mimeType="image/png", name=name))
        doc.textures.append(gl.Texture(sampler=0, source=len(doc.images) - 1, name=name))
        return len(doc.textures) - 1

    materials: dict[str, int] = {}
    for index, (name, contents) in enumerate(surfaces):
        material_name = rig.material_of(name) if rig is not None else name
        attributes, indices, arrays = _geometry(contents, accessor)
        if material_name not in materials:
            prefix = "" if index == 0 else f"{material_name}_"
            material = _material(material_name, contents, lambda map_name, png, p=prefix: texture(p + map_name, png), files)
            doc.materials.append(material)
            materials[material_name] = len(doc.materials) - 1
            if material.extensions and "KHR_materials_specular" not in extensions:
                extensions.append("KHR_materials_specular")
        primitive = gl.Primitive(attributes=attributes, indices=indices, material=materials[material_name], mode=4)
        mesh = gl.Mesh(name=name, primitives=[primitive])
        if contents.targets is not None:
            primitive.targets = _morph_targets(arrays, sparse_accessors)
            mesh.weights = [float(w) for w in contents.targets.weights.astype(np.float32)]
            mesh.extras = {"targetNames": list(contents.targets.names)}
        doc.meshes.append(mesh)
        doc.nodes.append(gl.Node(name=name, mesh=len(doc.meshes) - 1))
    shaped = [c.targets for _, c in surfaces if c.targets is not None]
    if shaped:  # every surface's targets have the same names and notes
        doc.asset.extras = {"blendshapeNames": shaped[0].naming.naming, "blendshapeNotes": shaped[0].notes}
        extensions.append("KHR_mesh_quantization")
    if rig is not None and animation is not None:
        roots = _animated_nodes(doc, rig, surfaces)
        _animation(doc, animation, surfaces, accessor)
    else:
        roots = list(range(len(surfaces)))
    doc.scenes.append(gl.Scene(nodes=roots))
    if extensions:
        doc.extensionsUsed = extensions
    if "KHR_mesh_quantization" in extensions:
        doc.extensionsRequired = ["KHR_mesh_quantization"]
    doc.buffers.append(gl.Buffer(byteLength=len(blob)))
    doc.set_binary_blob(bytes(blob))
    out = doc.save_to_bytes()
    return b"".join(out) if isinstance(out, list) else bytes(out)


def _bounds(arrays: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per (n_i, 3) array, the componentwise min and max of its values and 0 (a sparse accessor's
    elements not stored are zeros): two (len(arrays), 3) arrays, computed in one pass."""
    lengths = np.array([len(a) for a in arrays])
    low, high = np.zeros((len(arrays), 3)), np.zeros((len(arrays), 3))
    filled = np.flatnonzero(lengths)
    if len(filled):
        stacked = np.concatenate([arrays[i] for i in filled]).astype(np.int32)
        starts = np.concatenate([[0], np.cumsum(lengths[filled])[:-1]])
        low[filled] = np.minimum(np.minimum.reduceat(stacked, starts, axis=0), 0)
        high[filled] = np.maximum(np.maximum.reduceat(stacked, starts, axis=0), 0)
    return low, high


def _morph_items(targets: SurfaceTargets, vert: np.ndarray, n_vertices: int) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """Per target name, its ``POSITION`` then ``NORMAL`` sparse item ``(wedge indices, values,
    componentType)`` on the written vertices (wedges ``vert`` (W,) of ``n_vertices``):
    displacements in metres as normalized shorts (1/32767 m ≈ 31 µm steps; a wedge is stored when
    its displacement does not round to zero) and normal changes as normalized bytes (1/127 steps),
    stored where the normal turns by more than :data:`NORMAL_TARGET_MIN` (elsewhere a renderer
    keeps the neutral normal)."""
    items = []
    lookup = np.full(n_vertices, -1, dtype=np.int64)
    for target in targets.targets:
        lookup[:] = -1
        lookup[target.indices] = np.arange(len(target.indices))
        rows = lookup[vert]
        wedge = np.flatnonzero(rows >= 0)
        rows = rows[wedge]
        position = np.rint(np.clip(target.positions[rows] * (0.001 * 32767), -32767, 32767)).astype(np.int16)
        turned = np.linalg.norm(target.normals[rows], axis=1) > NORMAL_TARGET_MIN
        normal = np.rint(np.clip(target.normals[rows[turned]], -1.0, 1.0) * 127).astype(np.int8)
        keep = np.any(position != 0, axis=1)
        items += [(wedge[keep], position[keep], _SHORT), (wedge[turned], normal, _BYTE)]
    return items


def _morph_targets(arrays: _SurfaceArrays, sparse_accessors: Any) -> list[Any]:
    """One ``{"POSITION", "NORMAL"}`` target per name (:func:`_morph_items`), sparse accessors."""
    import pygltflib as gl

    accessors = sparse_accessors(len(arrays.vert), arrays.morph_items)
    return [gl.Attributes(POSITION=p, NORMAL=n) for p, n in zip(accessors[0::2], accessors[1::2])]


def _animated_nodes(doc: Any, rig: FaceRig, surfaces: list[tuple[str, SceneContents]]) -> list[int]:
    """Put the surfaces' nodes (one per surface, in order) under a ``head`` node; the eyes' nodes
    sit at their centres (metres). Returns the scene's root nodes."""
    import pygltflib as gl

    centres = dict(zip(EYE_NAMES, rig.centres))
    for index, (name, _) in enumerate(surfaces):
        if name in centres:
            doc.nodes[index].translation = [float(x) * 0.001 for x in centres[name]]
    doc.nodes.append(gl.Node(name=HEAD_NAME, children=list(range(len(surfaces)))))
    return [len(doc.nodes) - 1]


def _animation(doc: Any, take: ArkitTake, surfaces: list[tuple[str, SceneContents]], accessor: Any) -> None:
    """One animation: a ``weights`` channel per node with targets (the take's weights mapped to
    the targets, one shared sampler) and ``rotation`` channels for the head and eye nodes whose
    rotations the take has; keys at the take's times, linear."""
    import pygltflib as gl

    named = {node.name: i for i, node in enumerate(doc.nodes)}
    with_targets = [(name, c.targets) for name, c in surfaces if c.targets is not None]
    if not with_targets:
        raise InputError("<export>", "blendshapes", "an asset with blendshapes to animate", "none")
    times = accessor(take.times.astype(np.float32), "SCALAR", _FLOAT, None, bounds=True)
    animation = gl.Animation(name=Path(take.source).stem or "take")
    weights = target_weights(take, with_targets[0][1].naming)
    animation.samplers.append(gl.AnimationSampler(input=times, output=accessor(weights.astype(np.float32).ravel(), "SCALAR", _FLOAT, None),
                                                  interpolation="LINEAR"))
    for name, _ in with_targets:
        animation.channels.append(gl.AnimationChannel(sampler=0, target=gl.AnimationChannelTarget(node=named[name], path="weights")))
    for node, group in ((HEAD_NAME, "head"), *EYE_NAMES.items()):
        if group not in take.rotations or node not in named:
            continue
        output = accessor(rotations(take.rotations[group]).astype(np.float32), "VEC4", _FLOAT, None)
        animation.samplers.append(gl.AnimationSampler(input=times, output=output, interpolation="LINEAR"))
        animation.channels.append(gl.AnimationChannel(sampler=len(animation.samplers) - 1,
                                                      target=gl.AnimationChannelTarget(node=named[node], path="rotation")))
    doc.animations.append(animation)


@dataclass(frozen=True)
class _SurfaceArrays:
    """What one surface's glTF mesh holds that depends on its geometry alone (:func:`surface_arrays`):
    the written vertices' (wedges') ``positions`` (W, 3) float32 m, ``normals`` (W, 3) float32,
    ``texcoords`` (W, 2) float32 (None: untextured), ``tangents`` (W, 4) float32 (None: no normal
    map), the triangles ``tris`` (F, 3) int into the wedges, ``vert`` (W,) their geometry vertices, and
    the morph targets' sparse ``(indices, values, componentType)`` items (None without targets)."""

    positions: np.ndarray
    normals: np.ndarray
    texcoords: np.ndarray | None
    tangents: np.ndarray | None
    tris: np.ndarray
    vert: np.ndarray
    morph_items: list[tuple[np.ndarray, np.ndarray, int]] | None


def surface_arrays(contents: SceneContents | SceneGeometry, textured: bool, normal_mapped: bool) -> _SurfaceArrays:
    """The glTF arrays of one surface's geometry (:class:`_SurfaceArrays`) with UVs where
    ``textured`` and MikkTSpace tangents where ``normal_mapped``, made once per geometry and kept
    with it (``contents.derived``): ``facegeo reconstruct`` makes them in the export's first half
    (:func:`prepare_surface_arrays`), before the maps exist, and :func:`glb_bytes` finds them."""
    key = ("glb", bool(textured), bool(normal_mapped))
    made = contents.derived.get(key)
    if made is None:
        mesh = contents.mesh
        vert, uvi, tris = wedges(mesh.triangles, mesh.uv_triangles if textured else None)
        uv = mesh.uv[uvi] if textured else None
        tangents = None
        if normal_mapped:
            vert, uv, tris, tangents = _with_tangents(mesh, contents.normals, vert, uv, tris)
        texcoords = None if uv is None else np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1).astype(np.float32)
        targets = contents.targets
        made = _SurfaceArrays((mesh.vertices[vert] * 0.001).astype(np.float32), contents.normals[vert].astype(np.float32),
                              texcoords, tangents, tris, vert,
                              None if targets is None else _morph_items(targets, vert, len(mesh.vertices)))
        contents.derived[key] = made
    return made


def prepare_surface_arrays(geometries: list[SceneGeometry], parts: list[Asset], skin_maps: Iterable[str]) -> None:
    """Make the glTF arrays (:func:`surface_arrays`) of the skin's and the parts' scene
    ``geometries`` (:func:`facegeo.export.scene.scene_geometries`) before the maps exist: the
    skin's as a skin with ``skin_maps`` would be written (textured unless it carries none but the
    baked displacement; tangents with a normal map), each part's as its own maps and constants
    say. A guess that the written materials contradict is made again by :func:`glb_bytes`."""
    wanted = set(skin_maps) - {"displacement"}
    surface_arrays(geometries[0], bool(wanted), "normal" in wanted)
    for geometry, part in zip(geometries[1:], parts):
        inputs = material_inputs(part, None)
        surface_arrays(geometry, any(i.is_texture for i in inputs.values()), "normal" in inputs)


def _geometry(contents: SceneContents, accessor: Any) -> tuple[Any, int, _SurfaceArrays]:
    """The primitive's attributes and index accessor of one surface (wedges, tangents), and its
    arrays (:func:`surface_arrays`)."""
    import pygltflib as gl

    arrays = surface_arrays(contents, contents.textured, "normal" in contents.inputs)
    attributes = gl.Attributes(
        POSITION=accessor(arrays.positions, "VEC3", _FLOAT, _ARRAY_BUFFER, bounds=True),
        NORMAL=accessor(arrays.normals, "VEC3", _FLOAT, _ARRAY_BUFFER),
    )
    if arrays.texcoords is not None:
        attributes.TEXCOORD_0 = accessor(arrays.texcoords, "VEC2", _FLOAT, _ARRAY_BUFFER)
    if arrays.tangents is not None:
        attributes.TANGENT = accessor(arrays.tangents, "VEC4", _FLOAT, _ARRAY_BUFFER)
    tris = arrays.tris
    if len(arrays.vert) <= 65535:
        indices = accessor(tris.astype(np.uint16).ravel(), "SCALAR", _UNSIGNED_SHORT, _ELEMENT_ARRAY_BUFFER)
    else:
        indices = accessor(tris.astype(np.uint32).ravel(), "SCALAR", _UNSIGNED_INT, _ELEMENT_ARRAY_BUFFER)
    return attributes, indices, arrays


def _material(name: str, contents: SceneContents, texture: Any, files: TextureFiles) -> Any:
    """The metallic-roughness material of one surface; ``texture(map name, PNG bytes)`` adds an
    image and returns its texture index; the albedo and normal maps' files come from ``files``."""
    import pygltflib as gl

    inputs = contents.inputs
    pbr = gl.PbrMetallicRoughness(metallicFactor=0.0)
    material = gl.Material(name=f"{name}_material", pbrMetallicRoughness=pbr, alphaCutoff=None, doubleSided=False)
    if "albedo" in inputs:
        item = inputs["albedo"]
        if item.is_texture:
            pbr.baseColorTexture = gl.TextureInfo(index=texture("albedo", files.map_png("albedo", item.texture, 8)[0]))
            pbr.baseColorFactor = [1.0, 1.0, 1.0, 1.0]
        else:
            pbr.baseColorFactor = [float(x) for x in srgb_to_linear(np.asarray(item.value, np.float32))] + [1.0]
    else:
        pbr.baseColorFactor = [1.0, 1.0, 1.0, 1.0]
    if "roughness" in inputs and inputs["roughness"].is_texture:
        r = to_uint(inputs["roughness"].texture, 8)
        mr = np.stack([np.full_like(r, 255), r, np.zeros_like(r)], axis=-1)
        pbr.metallicRoughnessTexture = gl.TextureInfo(index=texture("metallicRoughness", png_bytes(mr)))
        pbr.roughnessFactor = 1.0
    else:
        pbr.roughnessFactor = float(inputs["roughness"].value) if "roughness" in inputs else DEFAULT_ROUGHNESS
    if "normal" in inputs:
        png, _ = files.map_png("normal", inputs["normal"].texture, 8)
        material.normalTexture = gl.NormalMaterialTexture(index=texture("normal", png), scale=1.0)
    if "specular" in inputs:
        item = inputs["specular"]
        factor = SPECULAR_F0_SCALE / 0.04  # 2: glTF's F0 is 0.04 × specularColor
        if item.is_texture:
            srgb = to_uint(linear_to_srgb(np.clip(item.texture, 0.0, 1.0)), 8)
            ext = {"specularColorFactor": [factor] * 3,
                   "specularColorTexture": {"index": texture("specular", png_bytes(np.repeat(srgb[:, :, None], 3, axis=2)))}}
        else:
            ext = {"specularColorFactor": [factor * float(item.value)] * 3}
        material.extensions = {"KHR_materials_specular": ext}
    return material


def _with_tangents(mesh, normals, vert, uv, tris):
    """MikkTSpace corner tangents (``facegeo.uv.tangents``, the frame the texture stage bakes
    normal maps in) and the wedge vertices split wherever corners of one wedge got different
    tangents (MikkTSpace may give a vertex one tangent per group of its triangles)."""
    from facegeo.uv.tangents import mesh_tangents

    corner = mesh_tangents(mesh.vertices, mesh.triangles, mesh.uv, mesh.uv_triangles, normals.astype(np.float32))
    rows = np.empty(tris.size, dtype=[("w", np.int64), ("t", np.float32, 4)])
    rows["w"] = tris.ravel()
    rows["t"] = corner.reshape(-1, 4)
    unique, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    wedge = unique["w"]
    return vert[wedge], uv[wedge], inverse.reshape(tris.shape), np.ascontiguousarray(unique["t"])


# -- validation ----------------------------------------------------------------------------------


class GltfValidatorMissing(RuntimeError):
    """node or the ``gltf-validator`` npm package is not installed."""


def find_gltf_validator() -> tuple[str, Path]:
    """``(node executable, gltf-validator package folder)``.

    Looks at ``$FACEGEO_GLTF_VALIDATOR``, then ``<sys.prefix>/node/node_modules/gltf-validator``
    (``npm install --prefix .venv/node gltf-validator``), then ``./node_modules``.

    Raises:
        GltfValidatorMissing: with the install command in its message.
    """
    node = shutil.which("node")
    if node is None:
        raise GltfValidatorMissing("node is not installed (apt-get install nodejs npm)")
    candidates = []
    env = os.environ.get(VALIDATOR_ENV_VAR)
    if env:
        candidates += [Path(env), Path(env) / "gltf-validator", Path(env) / "node_modules" / "gltf-validator"]
    candidates += [Path(sys.prefix) / "node" / "node_modules" / "gltf-validator", Path.cwd() / "node_modules" / "gltf-validator"]
    for c in candidates:
        if (c / "package.json").is_file() and (c / "index.js").is_file():
            return node, c
    raise GltfValidatorMissing(
        f"the gltf-validator npm package was not found (npm install --prefix {Path(sys.prefix) / 'node'} gltf-validator, "
        f"or set {VALIDATOR_ENV_VAR})")


_RUNNER = r"""
const fs = require('fs');
const validator = require(process.argv[1]);
const data = new Uint8Array(fs.readFileSync(process.argv[2]));
validator.validateBytes(data, {uri: process.argv[2], maxIssues: 1000, writeTimestamp: false})
  .then((report) => { process.stdout.write(JSON.stringify(report)); })
  .catch((error) => { process.stderr.write(String(error)); process.exit(1); });
"""


def validate_glb(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The Khronos glTF-Validator report of a file (its JSON as a dict): ``report["issues"]``
    has ``numErrors``, ``numWarnings``, ``numInfos``, ``numHints`` and ``messages``.

    Raises:
        GltfValidatorMissing: node or the package is absent.
        RuntimeError: the validator itself failed.
    """
    node, package = find_gltf_validator()
    result = subprocess.run([node, "-e", _RUNNER, str(package), str(Path(path).resolve())],
                            capture_output=True, text=True, timeout=300)
    if result.returncode != 0:
        raise RuntimeError(f"gltf-validator failed on {path}: {result.stderr.strip()}")
    return json.loads(result.stdout)
