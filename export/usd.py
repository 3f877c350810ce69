"""USD export: ``.usda``, ``.usdc`` and ``.usdz`` with a ``UsdPreviewSurface`` material.

The stage (DESIGN.md, "Conventions"): ``upAxis = "Y"``, ``metersPerUnit = 0.001`` (points in mm),
a default prim ``/<name>`` (an Xform of kind ``component``) holding

* ``/<name>/mesh``, a ``Mesh``: points, ``faceVertexCounts``/``faceVertexIndices`` (triangles,
  counter-clockwise = ``rightHanded``), ``normals`` (vertex interpolation, smooth,
  area-weighted), ``subdivisionScheme = "none"`` (the mesh is already subdivided to the level
  asked for; USD's default, Catmull-Clark, would make renderers smooth it again and ignore the
  normals), ``extent``, and - only when a texture is used - ``primvars:st`` (``texCoord2f[]``,
  face-varying, indexed: the Asset's ``uv`` and ``uv_triangles``);
* ``/<name>/mtl/material``, a ``Material`` bound to the mesh (``MaterialBindingAPI``) whose
  surface is a ``UsdPreviewSurface``:

  - albedo -> ``diffuseColor``: ``UsdUVTexture`` (``sourceColorSpace = "sRGB"``, 8-bit PNG), or
    the constant converted to linear;
  - normal -> ``normal``: ``UsdUVTexture`` ``raw`` with ``scale = (2, 2, 2, 1)`` and
    ``bias = (−1, −1, −1, 0)`` (tangent space, OpenGL +Y, MikkTSpace);
  - roughness -> ``roughness`` (texture ``r`` or value; 0.5 when the asset has none);
  - specular: the Asset's F0 = 0.08 × specular is written with ``useSpecularWorkflow = 1`` and
    ``specularColor`` = F0: the specular texture (``raw``) through ``UsdUVTexture`` with
    ``scale = (0.08, 0.08, 0.08, 1)``, or the constant 0.08 × s. The preview surface's
    specularColor is exactly "the colour at 0° incidence, edge colour white", the Asset's model
    (F90 = 1); the metallic workflow's ``ior`` would need a per-texel IOR
    (ior = (1 + √F0)/(1 − √F0)) that no texture input can carry linearly. Without a specular
    input the metallic workflow with the default ``ior = 1.5`` gives F0 = 0.04 (= specular 0.5);
  - ``metallic = 0`` always (skin);
  - displacement: baked into the points (``displacement="bake"``, the default), or with
    ``displacement="texture"`` the ``displacement`` input: a 16-bit ``raw`` texture whose
    ``scale``/``bias`` turn texels into millimetres (stage units), connected to the material's
    displacement output; the points are then the undisplaced (subdivided) surface.

Parts (``asset.parts``: eyeballs, teeth, ...): each is its own ``Mesh`` at
``/<name>/parts/<part>`` (under an ``Xform``), with its own material ``/<name>/mtl/<part>`` built
the same way and bound to it; its textures are ``<part>_<map>.png``. Parts are written at level 0
(they carry no displacement).

Only inputs the scene uses are authored: no texture for a constant map (a value is), no
``primvars:st`` without textures. ``.usdz`` is made with ``UsdUtils.CreateNewUsdzPackage`` from a
``.usdc`` root layer and its PNGs; ``.usda``/``.usdc`` write their textures next to the layer in
``<stem>_textures/`` (relative paths). Files are written atomically (nothing partial on failure).

Blendshapes (``blendshapes="arkit"``, the default, or ``"ict"``; issue 28): the root is a
``UsdSkel`` ``SkelRoot``; the meshes' points are the neutral mesh; each mesh with blendshapes gets
``skel:blendShapes`` and ``skel:blendShapeTargets`` and one ``BlendShape`` prim per name under it
(sparse ``pointIndices``, ``offsets`` in mm, ``normalOffsets``); a ``Skeleton``
(``/<name>/skeleton``: ``head``, and the eyes when there are eyeballs) with a ``SkelAnimation``
(``/<name>/animation``) holds the fitted weights, or a take's time samples
(:func:`_write_skeleton`); ``customData`` of the root records the naming and its notes.
:func:`skel_points` evaluates a file with UsdSkel's own queries.

:func:`validate_usd` runs every validator usd-core registers (``pxr.UsdValidation``) on a file;
:func:`check_usd` checks that the stage opens, every texture path resolves (inside the package for
usdz) and the material binds.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from facegeo.arkit import ArkitTake
from facegeo.asset import SPECULAR_F0_SCALE, Asset
from facegeo.colour import srgb_to_linear
from facegeo.errors import InputError, OutputError
from facegeo.export.animation import EYE_NAMES, HEAD_NAME, rotations, target_weights
from facegeo.export.scene import SceneContents, scene_surfaces
from facegeo.parts import EYEBALLS_PART, eyeball_centres
from facegeo.export.textures import DEFAULT_ROUGHNESS, TextureFiles, encode_map
from facegeo.image_files import png_bytes
from facegeo.staged_output import WRITE_FAULTS, StagedOutput, atomic_write_bytes, scratch_folder

__all__ = ["write_usd", "validate_usd", "check_usd", "skel_points", "UsdCheck", "USD_SUFFIXES", "WRITER_LIBRARIES"]

#: The pxr modules :func:`write_usd` imports when it runs (kept out of ``import facegeo``); a
#: caller that writes on threads imports them first (:func:`facegeo.export.writers.scene_writers`).
WRITER_LIBRARIES = ("pxr.Ar", "pxr.Gf", "pxr.Kind", "pxr.Sdf", "pxr.Tf", "pxr.Usd", "pxr.UsdGeom", "pxr.UsdShade",
                    "pxr.UsdSkel", "pxr.UsdUtils", "pxr.Vt")

USD_SUFFIXES = (".usda", ".usdc", ".usd", ".usdz")


def write_usd(
    asset: Asset,
    path: str | os.PathLike[str],
    *,
    level: int = 0,
    displacement: str = "bake",
    maps: Iterable[str] | None = None,
    linear_bits: int = 8,
    uv_interpolation: str = "surface",
    blendshapes: str | None = "arkit",
    animation: ArkitTake | None = None,
    surfaces: list[tuple[str, SceneContents]] | None = None,
    texture_files: TextureFiles | None = None,
) -> Path:
    """Write ``asset`` as a USD file; the suffix of ``path`` picks the format (.usda, .usdc,
    .usd = usdc, .usdz). ``level``: Loop subdivision levels; ``displacement``: "bake" or
    "texture"; ``maps``: the map names to carry (default all the asset has); ``linear_bits``:
    8 or 16 for the normal, roughness and specular textures (albedo is 8-bit sRGB, displacement
    16-bit); ``blendshapes``: the blend shapes' names, "arkit" or "ict", or None to leave them
    out (a static asset); ``animation``: a take to animate the face with; ``surfaces``: the
    asset's :func:`facegeo.export.scene.scene_surfaces` with these options, if already computed
    (shared with another format); ``texture_files``: the maps' PNG files shared with other
    outputs (default: made here). Returns the path written.

    Raises:
        InputError: unknown suffix, bad options, or a map asked for that the asset lacks.
    """
    target = Path(path)
    suffix = target.suffix.lower()
    if suffix not in USD_SUFFIXES:
        raise InputError(target, "file name", f"a USD suffix ({', '.join(USD_SUFFIXES)})", target.suffix or "none")
    if linear_bits not in (8, 16):
        raise InputError(target, "linear_bits", "8 or 16", repr(linear_bits))
    if animation is not None and blendshapes is None:
        raise InputError(target, "blendshapes", "a naming (arkit or ict) to animate the face with", "none")
    if surfaces is None:
        surfaces = scene_surfaces(asset, level=level, displacement=displacement, maps=maps, uv_interpolation=uv_interpolation,
                                  blendshapes=blendshapes)
    contents = surfaces[0][1]
    parts = [(_prim_name(name), part) for name, part in surfaces[1:]]
    if animation is not None and contents.targets is None and not any(p.targets for _, p in parts):
        raise InputError(target, "blendshapes", "an asset with blendshapes to animate", "none")
    name = _prim_name(asset.name)
    files = TextureFiles() if texture_files is None else texture_files
    if suffix == ".usdz":
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            with scratch_folder(target.parent) as tmp:  # not /tmp: a killed worker's is removed by the next run
                root = Path(tmp) / f"{name}.usdc"
                _write_layer(contents, parts, root, name, "textures", linear_bits, files, animation)
                package = Path(tmp) / f"{name}.usdz"
                from pxr import Sdf, UsdUtils

                if not UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(root)), str(package)):  # pragma: no cover
                    raise RuntimeError(f"UsdUtils.CreateNewUsdzPackage failed for {root}")
                data = package.read_bytes()
        except OutputError as exc:  # the package is built in a scratch folder: name the target
            raise OutputError(target, exc.problem) from None
        except OSError as exc:
            if exc.errno not in WRITE_FAULTS:
                raise
            raise OutputError(target, WRITE_FAULTS[exc.errno]) from None
        atomic_write_bytes(target, data)
        return target
    with StagedOutput(target.parent) as stage:
        layer = stage.path(target.name)
        _write_layer(contents, parts, layer, name, f"{target.stem}_textures", linear_bits, files, animation)
    return target


# -- layer ---------------------------------------------------------------------------------------


def _prim_name(name: str) -> str:
    from pxr import Tf

    ident = Tf.MakeValidIdentifier(name or "face")
    return ident if ident else "face"


def _write_layer(contents: SceneContents, parts: list[tuple[str, SceneContents]], layer_path: Path, name: str,
                 texture_dir: str, linear_bits: int, files: TextureFiles, animation: ArkitTake | None = None) -> None:
    """The stage: the skin at ``/<name>/mesh`` with ``/<name>/mtl/material``, and each part at
    ``/<name>/parts/<part>`` with ``/<name>/mtl/<part>`` (its textures ``<part>_<map>.png``, the
    maps' files from ``files``); with blend shapes the root is a ``SkelRoot`` holding the
    skeleton (:func:`_write_skeleton`)."""
    from pxr import Kind, Tf, Usd, UsdGeom, UsdSkel

    stage = Usd.Stage.CreateNew(str(layer_path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.001)
    skinned = contents.targets is not None or any(p.targets is not None for _, p in parts)
    root = (UsdSkel.Root if skinned else UsdGeom.Xform).Define(stage, f"/{name}")
    stage.SetDefaultPrim(root.GetPrim())
    Usd.ModelAPI(root.GetPrim()).SetKind(Kind.Tokens.component)
    UsdGeom.Scope.Define(stage, f"/{name}/mtl")
    textures: dict[str, bytes] = {}
    _write_surface(stage, contents, f"/{name}/mesh", f"/{name}/mtl/material", f"{texture_dir}/", linear_bits, files, textures)
    if parts:
        UsdGeom.Xform.Define(stage, f"/{name}/parts")
    for part_name, part in parts:
        _write_surface(stage, part, f"/{name}/parts/{part_name}", f"/{name}/mtl/{part_name}",
                       f"{texture_dir}/{part_name}_", linear_bits, files, textures)
    if skinned:
        surfaces = [(f"/{name}/mesh", contents)] + [(f"/{name}/parts/{p}", c) for p, c in parts]
        _write_skeleton(stage, f"/{name}", surfaces, animation)
    for rel, data in textures.items():
        out = layer_path.parent / rel
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(data)
    try:
        stage.GetRootLayer().Save()
    except Tf.ErrorException as exc:  # usd-core reports a failed write (full disk, size limit) this way
        raise OutputError(layer_path, f"USD could not write it ({_usd_reason(exc)})") from None


def _write_surface(stage: Any, contents: SceneContents, mesh_path: str, material_path: str, texture_prefix: str,
                   linear_bits: int, files: TextureFiles, textures: dict[str, bytes]) -> None:
    """One Mesh prim and its bound UsdPreviewSurface material; texture files go into ``textures``
    (relative path -> PNG bytes) as ``<texture_prefix><map>.png``, the maps' from ``files``."""
    from pxr import Gf, Sdf, UsdGeom, UsdShade, Vt

    mesh_data = contents.mesh
    points = mesh_data.vertices.astype(np.float32)
    mesh = UsdGeom.Mesh.Define(stage, mesh_path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(mesh_data.triangles), 3, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(mesh_data.triangles.ravel().astype(np.int32)))
    mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(contents.normals.astype(np.float32)))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, points.min(axis=0))), Gf.Vec3f(*map(float, points.max(axis=0)))]))
    if contents.textured:
        st = UsdGeom.PrimvarsAPI(mesh.GetPrim()).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
        st.Set(Vt.Vec2fArray.FromNumpy(mesh_data.uv.astype(np.float32)))
        st.SetIndices(Vt.IntArray.FromNumpy(mesh_data.uv_triangles.ravel().astype(np.int32)))

    material = UsdShade.Material.Define(stage, material_path)
    mpath = material.GetPath()
    surface = UsdShade.Shader.Define(stage, mpath.AppendChild("PreviewSurface"))
    surface.CreateIdAttr("UsdPreviewSurface")
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)

    reader = None

    def texture(map_name: str, png: bytes, colorspace: str, scale: tuple, bias: tuple) -> Any:
        nonlocal reader
        if reader is None:
            reader = UsdShade.Shader.Define(stage, mpath.AppendChild("stReader"))
            reader.CreateIdAttr("UsdPrimvarReader_float2")
            reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
            reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
        rel = f"{texture_prefix}{map_name}.png"
        textures[rel] = png
        tex = UsdShade.Shader.Define(stage, mpath.AppendChild(f"{map_name}Texture"))
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(f"./{rel}"))
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(colorspace)
        tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
        tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("clamp")
        if scale != (1.0, 1.0, 1.0, 1.0):
            tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*scale))
        if bias != (0.0, 0.0, 0.0, 0.0):
            tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*bias))
        return tex

    inputs = contents.inputs
    if "albedo" in inputs:
        item = inputs["albedo"]
        diffuse = surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f)
        if item.is_texture:
            tex = texture("albedo", files.map_png("albedo", item.texture, 8)[0], "sRGB", (1.0, 1.0, 1.0, 1.0), (0.0, 0.0, 0.0, 0.0))
            diffuse.ConnectToSource(tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
        else:
            diffuse.Set(Gf.Vec3f(*map(float, srgb_to_linear(np.asarray(item.value, dtype=np.float32)))))
    if "normal" in inputs:  # material_inputs only keeps a normal map that changes something
        tex = texture("normal", files.map_png("normal", inputs["normal"].texture, linear_bits)[0], "raw", (2.0, 2.0, 2.0, 1.0), (-1.0, -1.0, -1.0, 0.0))
        surface.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
    rough = surface.CreateInput("roughness", Sdf.ValueTypeNames.Float)
    if "roughness" in inputs and inputs["roughness"].is_texture:
        tex = texture("roughness", files.map_png("roughness", inputs["roughness"].texture, linear_bits)[0], "raw", (1.0, 1.0, 1.0, 1.0), (0.0, 0.0, 0.0, 0.0))
        rough.ConnectToSource(tex.CreateOutput("r", Sdf.ValueTypeNames.Float))
    else:
        rough.Set(float(inputs["roughness"].value) if "roughness" in inputs else DEFAULT_ROUGHNESS)
    if "specular" in inputs:
        item = inputs["specular"]
        surface.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
        spec = surface.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f)
        if item.is_texture:
            img, _ = encode_map("specular", np.repeat(item.texture[:, :, None], 3, axis=2), linear_bits)
            k = SPECULAR_F0_SCALE
            tex = texture("specular", png_bytes(img), "raw", (k, k, k, 1.0), (0.0, 0.0, 0.0, 0.0))
            spec.ConnectToSource(tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
        else:
            f0 = SPECULAR_F0_SCALE * float(item.value)
            spec.Set(Gf.Vec3f(f0, f0, f0))
    if "displacement" in inputs:  # only in displacement="texture" mode
        item = inputs["displacement"]
        disp = surface.CreateInput("displacement", Sdf.ValueTypeNames.Float)
        if item.is_texture:
            png, enc = files.map_png("displacement", item.texture, 16)
            s, o = float(enc["scale"]), float(enc["offset"])
            tex = texture("displacement", png, "raw", (s, s, s, 1.0), (o, o, o, 0.0))
            disp.ConnectToSource(tex.CreateOutput("r", Sdf.ValueTypeNames.Float))
        else:
            disp.Set(float(item.value))
        material.CreateDisplacementOutput().ConnectToSource(surface.ConnectableAPI(), "displacement")

    binding = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    binding.Bind(material)


def _write_skeleton(stage: Any, root: str, surfaces: list[tuple[str, SceneContents]], take: ArkitTake | None) -> None:
    """UsdSkel: the blend shapes of every surface with targets, a ``Skeleton`` (``<root>/skeleton``)
    and its ``SkelAnimation`` (``<root>/animation``) with the fitted weights, or the take's
    time-sampled weights and joint rotations.

    Joints: ``head`` (every mesh is bound to it rigidly; it turns about the model's origin) and,
    with an eyeballs part, ``head/eye_left`` and ``head/eye_right`` at the eyes' centres (each
    eyeball vertex is bound to its eye; :mod:`facegeo.export.animation`). Each mesh with targets
    gets ``skel:blendShapes`` (the target names) and ``skel:blendShapeTargets``: one
    ``BlendShape`` prim per target under the mesh, with sparse ``pointIndices``, ``offsets``
    (mm) and ``normalOffsets``. UsdSkel evaluates the mesh at the animation's weights as
    points + Σ weight × offsets (``UsdSkel.BlendShapeQuery``)."""
    from pxr import Gf, Usd, UsdSkel, Vt

    eyeballs = next((c for path, c in surfaces if path.rsplit("/", 1)[-1] == _prim_name(EYEBALLS_PART)), None)
    joints = [HEAD_NAME]
    rest = [Gf.Matrix4d(1.0)]
    side = None
    if eyeballs is not None:
        side, centres = eyeball_centres(eyeballs.mesh.vertices)
        for eye, centre in zip(EYE_NAMES, centres):
            joints.append(f"{HEAD_NAME}/{eye}")
            rest.append(Gf.Matrix4d(1.0).SetTranslate(Gf.Vec3d(*map(float, centre))))
    skeleton = UsdSkel.Skeleton.Define(stage, f"{root}/skeleton")
    skeleton.CreateJointsAttr(Vt.TokenArray(joints))
    skeleton.CreateBindTransformsAttr(Vt.Matrix4dArray(rest))
    skeleton.CreateRestTransformsAttr(Vt.Matrix4dArray(rest))
    anim = UsdSkel.Animation.Define(stage, f"{root}/animation")
    UsdSkel.BindingAPI.Apply(skeleton.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    anim.CreateJointsAttr(Vt.TokenArray(joints))
    anim.CreateTranslationsAttr(Vt.Vec3fArray([Gf.Vec3f(m.ExtractTranslation()) for m in rest]))
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1.0, 1.0, 1.0)] * len(joints)))
    rotations_attr = anim.CreateRotationsAttr(Vt.QuatfArray([Gf.Quatf(1.0)] * len(joints)))
    shaped = None  # the targets of a surface (every surface's have the same names and weights)
    for path, contents in surfaces:
        prim = stage.GetPrimAtPath(path)
        binding = UsdSkel.BindingAPI.Apply(prim)
        binding.CreateSkeletonRel().SetTargets([skeleton.GetPath()])
        binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))
        if contents is eyeballs and side is not None:
            binding.CreateJointIndicesPrimvar(False, 1).Set(Vt.IntArray.FromNumpy(np.where(side, 1, 2).astype(np.int32)))
            binding.CreateJointWeightsPrimvar(False, 1).Set(Vt.FloatArray.FromNumpy(np.ones(len(side), np.float32)))
        else:
            binding.CreateJointIndicesPrimvar(True, 1).Set(Vt.IntArray([0]))
            binding.CreateJointWeightsPrimvar(True, 1).Set(Vt.FloatArray([1.0]))
        targets = contents.targets
        if targets is None:
            continue
        shaped = targets
        binding.CreateBlendShapesAttr(Vt.TokenArray(list(targets.names)))
        shape_paths = []
        for target in targets.targets:
            shape = UsdSkel.BlendShape.Define(stage, f"{path}/{target.name}")
            shape.CreatePointIndicesAttr(Vt.IntArray.FromNumpy(target.indices.astype(np.int32)))
            shape.CreateOffsetsAttr(Vt.Vec3fArray.FromNumpy(target.positions))
            shape.CreateNormalOffsetsAttr(Vt.Vec3fArray.FromNumpy(target.normals))
            shape_paths.append(shape.GetPath())
        binding.CreateBlendShapeTargetsRel().SetTargets(shape_paths)
    assert shaped is not None  # _write_layer calls this only with targets
    anim.CreateBlendShapesAttr(Vt.TokenArray(list(shaped.names)))
    weights_attr = anim.CreateBlendShapeWeightsAttr(Vt.FloatArray.FromNumpy(shaped.weights.astype(np.float32)))
    root_prim = stage.GetPrimAtPath(root)
    root_prim.SetCustomDataByKey("blendshapeNames", shaped.naming.naming)
    root_prim.SetCustomDataByKey("blendshapeNotes", Vt.StringArray(shaped.notes))
    if take is None:
        return
    fps = take.fps
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetStartTimeCode(0.0)
    stage.SetEndTimeCode(float(take.times[-1] * fps))
    frames = target_weights(take, shaped.naming).astype(np.float32)
    quats = {group: rotations(take.rotations[group]) for group in ("head", *EYE_NAMES.values()) if group in take.rotations}
    groups = ["head", *EYE_NAMES.values()][:len(joints)]
    for k, t in enumerate(take.times):
        code = Usd.TimeCode(float(t * fps))
        weights_attr.Set(Vt.FloatArray.FromNumpy(frames[k]), code)
        if quats:
            rotations_attr.Set(Vt.QuatfArray([_quatf(quats[g][k]) if g in quats else Gf.Quatf(1.0) for g in groups]), code)


def _quatf(xyzw: np.ndarray) -> Any:
    """Gf.Quatf (real first) of an (x, y, z, w) quaternion."""
    from pxr import Gf

    x, y, z, w = (float(v) for v in xyzw)
    return Gf.Quatf(w, x, y, z)


def _usd_reason(exc: Exception) -> str:
    """The first quoted reason of a usd-core error (its message lists every C++ frame)."""
    reasons = re.findall(r": '([^']+)'", str(exc))
    return reasons[0] if reasons else str(exc).strip().splitlines()[0]


# -- checks --------------------------------------------------------------------------------------


def validate_usd(path: str | os.PathLike[str]) -> list[tuple[str, str, str]]:
    """Run every validator usd-core registers on the stage at ``path``.

    Returns ``[(type, validator name, message)]`` for every reported issue; ``type`` is
    ``"Error"``, ``"Warn"`` or ``"Info"`` (so ``[e for e in result if e[0] == "Error"]`` are the
    errors).
    """
    from pxr import Usd, UsdValidation

    stage = Usd.Stage.Open(str(path))
    if stage is None:  # pragma: no cover - Open raises for unreadable files
        raise InputError(path, "stage", "a USD file that opens")
    registry = UsdValidation.ValidationRegistry()
    validators = registry.GetOrLoadAllValidators()
    context = UsdValidation.ValidationContext(validators)
    out = []
    for error in context.Validate(stage):
        if error.HasNoError():
            continue
        validator = error.GetValidator()
        vname = validator.GetMetadata().name if validator is not None else ""
        out.append((str(error.GetType()).rsplit(".", 1)[-1], str(vname), error.GetErrorAsString()))
    return out


def skel_points(path: str | os.PathLike[str], time: float | None = None,
                weights: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """The points of every skinned mesh of a USD file as UsdSkel itself evaluates them
    (``UsdSkel.Cache``, ``UsdSkel.BlendShapeQuery``, then the skeleton's linear blend skinning) at
    ``time`` (a time code; None: the default values, i.e. the fitted weights of a static file):
    mesh prim path -> (V, 3) float64, the stage's units (mm). ``weights``: blend shape name ->
    weight to evaluate instead of the animation's (the others 0; in the session layer, the file
    is not changed). Meshes outside a ``SkelRoot`` are left out.

    Raises:
        InputError: a name in ``weights`` that no animation has.
    """
    from pxr import Usd, UsdSkel, Vt

    stage = Usd.Stage.Open(str(path))
    code = Usd.TimeCode.Default() if time is None else Usd.TimeCode(float(time))
    if weights is not None:
        stage.SetEditTarget(stage.GetSessionLayer())
        animations = [UsdSkel.Animation(p) for p in stage.Traverse() if p.IsA(UsdSkel.Animation)]
        known = {str(n) for a in animations for n in a.GetBlendShapesAttr().Get()}
        unknown = sorted(set(weights) - known)
        if unknown:
            raise InputError(path, "blend shape", f"names among the animation's ({len(known)})", ", ".join(unknown))
        for anim in animations:
            names = [str(n) for n in anim.GetBlendShapesAttr().Get()]
            anim.GetBlendShapeWeightsAttr().Set(Vt.FloatArray([float(weights.get(n, 0.0)) for n in names]), code)
    cache = UsdSkel.Cache()
    out: dict[str, np.ndarray] = {}
    for root_prim in stage.Traverse():
        if not root_prim.IsA(UsdSkel.Root):
            continue
        cache.Populate(UsdSkel.Root(root_prim), Usd.PrimDefaultPredicate)
        for binding in cache.ComputeSkelBindings(UsdSkel.Root(root_prim), Usd.PrimDefaultPredicate):
            skel_query = cache.GetSkelQuery(binding.GetSkeleton())
            anim_query = skel_query.GetAnimQuery()
            xforms = skel_query.ComputeSkinningTransforms(code)
            for skinning in binding.GetSkinningTargets():
                prim = skinning.GetPrim()
                points = prim.GetAttribute("points").Get(code)
                if skinning.HasBlendShapes() and anim_query:
                    weights = skinning.GetBlendShapeMapper().Remap(anim_query.ComputeBlendShapeWeights(code))
                    shapes = UsdSkel.BlendShapeQuery(UsdSkel.BindingAPI(prim))
                    sub_weights, indices, sub_indices = shapes.ComputeSubShapeWeights(weights)
                    shapes.ComputeDeformedPoints(sub_weights, indices, sub_indices, shapes.ComputeBlendShapePointIndices(),
                                                 shapes.ComputeSubShapePointOffsets(), points)
                skinning.ComputeSkinnedPoints(xforms, points, code)
                out[str(prim.GetPath())] = np.array(points, dtype=np.float64)
    return out


@dataclass
class UsdCheck:
    """What :func:`check_usd` found (the skin's mesh and material; the parts by name)."""

    default_prim: str
    up_axis: str
    meters_per_unit: float
    mesh_path: str
    material_path: str
    textures: dict[str, str] = field(default_factory=dict)  # the skin's: shader name -> resolved path
    primvars: list[str] = field(default_factory=list)
    n_points: int = 0
    parts: dict[str, str] = field(default_factory=dict)  # part mesh path -> its bound material path
    part_textures: dict[str, str] = field(default_factory=dict)  # "<part>/<shader name>" -> resolved path


def check_usd(path: str | os.PathLike[str]) -> UsdCheck:
    """Open the stage, resolve every ``UsdUVTexture`` file (inside the package for ``.usdz``) and
    read each mesh's bound material (the skin at ``<default prim>/mesh``, parts under
    ``<default prim>/parts``). Raises ``AssertionError`` naming what failed."""
    from pxr import Ar, Usd, UsdGeom, UsdShade

    stage = Usd.Stage.Open(str(path))
    assert stage is not None, f"{path}: stage does not open"
    prim = stage.GetDefaultPrim()
    assert prim and prim.IsValid(), f"{path}: no default prim"
    meshes = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    skin = [p for p in meshes if p.GetPath() == prim.GetPath().AppendChild("mesh")]
    assert len(skin) == 1, f"{path}: expected the mesh {prim.GetPath()}/mesh, found {[str(p.GetPath()) for p in meshes]}"
    others = [p for p in meshes if p != skin[0]]
    assert all(p.GetParent().GetName() == "parts" for p in others), f"{path}: meshes outside {prim.GetPath()}/parts"
    is_package = str(path).lower().endswith(".usdz")
    resolver = Ar.GetResolver()

    def bound(mesh_prim: Any) -> tuple[Any, dict[str, str]]:
        material, _ = UsdShade.MaterialBindingAPI(mesh_prim).ComputeBoundMaterial()
        assert material and material.GetPrim().IsValid(), f"{path}: {mesh_prim.GetPath()} has no bound material"
        surface = material.ComputeSurfaceSource()[0]
        assert surface and surface.GetIdAttr().Get() == "UsdPreviewSurface", f"{path}: surface is not a UsdPreviewSurface"
        textures = {}
        for shader_prim in Usd.PrimRange(material.GetPrim()):
            shader = UsdShade.Shader(shader_prim)
            if not shader or shader.GetIdAttr().Get() != "UsdUVTexture":
                continue
            asset_path = shader.GetInput("file").Get()
            resolved = asset_path.resolvedPath if asset_path is not None else ""
            assert resolved, f"{path}: {shader_prim.GetPath()} file {asset_path} does not resolve"
            if is_package:
                inside = "[" in resolved and Path(resolved.split("[", 1)[0]).resolve() == Path(path).resolve()
                assert inside, f"{path}: {asset_path} resolves outside the package: {resolved}"
            data = resolver.OpenAsset(Ar.ResolvedPath(resolved))
            assert data is not None and data.GetSize() > 0, f"{path}: {resolved} cannot be read"
            textures[shader_prim.GetName()] = resolved
        return material, textures

    mesh = UsdGeom.Mesh(skin[0])
    material, textures = bound(skin[0])
    parts, part_textures = {}, {}
    for p in others:
        part_material, found = bound(p)
        parts[str(p.GetPath())] = str(part_material.GetPath())
        part_textures.update({f"{p.GetName()}/{k}": v for k, v in found.items()})
    primvars = [pv.GetPrimvarName() for pv in UsdGeom.PrimvarsAPI(mesh.GetPrim()).GetAuthoredPrimvars()]
    return UsdCheck(
        default_prim=str(prim.GetPath()),
        up_axis=str(UsdGeom.GetStageUpAxis(stage)),
        meters_per_unit=float(UsdGeom.GetStageMetersPerUnit(stage)),
        mesh_path=str(mesh.GetPath()),
        material_path=str(material.GetPath()),
        textures=textures,
        primvars=[str(p) for p in primvars],
        n_points=len(mesh.GetPointsAttr().Get()),
        parts=parts,
        part_textures=part_textures,
    )
