"""USD export: validators, stage conventions, material wiring, usdz packaging (facegeo.export.usd)."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, UsdShade, UsdValidation

from facegeo.errors import InputError
from facegeo.export.usd import check_usd, validate_usd, write_usd
from facegeo.export.writers import export_asset
from test_export_support import ict_asset, synthetic_maps


def _shader(stage, name):
    prim = stage.GetPrimAtPath(f"/face/mtl/material/{name}")
    return UsdShade.Shader(prim) if prim and prim.IsValid() else None


def _surface(stage):
    return _shader(stage, "PreviewSurface")


@pytest.mark.parametrize("suffix", ["usda", "usdc", "usdz"])
@pytest.mark.parametrize("displacement", ["bake", "texture"])
def test_every_registered_validator_passes(tmp_path, suffix, displacement):
    path = write_usd(ict_asset(), tmp_path / f"face.{suffix}", level=1, displacement=displacement)
    issues = validate_usd(path)
    assert [i for i in issues if i[0] == "Error"] == []
    assert issues == []  # not even warnings
    report = check_usd(path)
    assert report.default_prim == "/face" and report.up_axis == "Y" and report.meters_per_unit == 0.001
    assert report.primvars == ["st"]
    expected = {"albedoTexture", "normalTexture", "roughnessTexture", "specularTexture"}
    if displacement == "texture":
        expected.add("displacementTexture")
    assert set(report.textures) == expected
    if suffix == "usdz":  # every texture resolves inside the package
        assert all(p.startswith(str(path.resolve())) and p.endswith(".png]") for p in report.textures.values())


def test_validators_are_loaded_and_catch_errors(tmp_path):
    """The validation really runs: a stage with the mistakes the writer avoids fails it."""
    assert len(UsdValidation.ValidationRegistry().GetOrLoadAllValidators()) >= 20
    stage = Usd.Stage.CreateNew(str(tmp_path / "bad.usda"))
    mesh = UsdGeom.Mesh.Define(stage, "/m")
    material = UsdShade.Material.Define(stage, "/m/material")
    reader = UsdShade.Shader.Define(stage, "/m/material/reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    mesh.GetPrim().CreateRelationship("material:binding").SetTargets([material.GetPath()])
    stage.GetRootLayer().Save()
    names = {i[1] for i in validate_usd(tmp_path / "bad.usda") if i[0] == "Error"}
    assert {"usdShadeValidators:ShaderSdrCompliance", "usdShadeValidators:MaterialBindingApiAppliedValidator",
            "usdGeomValidators:StageMetadataChecker", "usdValidation:StageMetadataChecker"} <= names


def test_stage_geometry_and_material_wiring(tmp_path):
    a = ict_asset()
    path = write_usd(a, tmp_path / "face.usda", level=0, displacement="texture")
    stage = Usd.Stage.Open(str(path))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/face/mesh"))
    np.testing.assert_allclose(np.array(mesh.GetPointsAttr().Get()), a.vertices, atol=1e-4)
    np.testing.assert_array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), a.triangles)
    assert mesh.GetSubdivisionSchemeAttr().Get() == "none" and mesh.GetNormalsInterpolation() == "vertex"
    st = UsdGeom.PrimvarsAPI(mesh.GetPrim()).GetPrimvar("st")
    assert st.GetInterpolation() == "faceVarying" and st.IsIndexed()
    np.testing.assert_array_equal(np.array(st.GetIndices()).reshape(-1, 3), a.uv_triangles)
    np.testing.assert_allclose(np.array(st.Get()), a.uv, atol=1e-7)
    normals = np.array(mesh.GetNormalsAttr().Get())
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)

    surface = _surface(stage)
    assert surface.GetInput("metallic").Get() == 0.0
    assert surface.GetInput("useSpecularWorkflow").Get() == 1
    spec = _shader(stage, "specularTexture")
    assert tuple(spec.GetInput("scale").Get()) == pytest.approx((0.08, 0.08, 0.08, 1.0))
    normal = _shader(stage, "normalTexture")
    assert normal.GetInput("sourceColorSpace").Get() == "raw"
    assert tuple(normal.GetInput("scale").Get()) == (2, 2, 2, 1) and tuple(normal.GetInput("bias").Get()) == (-1, -1, -1, 0)
    assert _shader(stage, "albedoTexture").GetInput("sourceColorSpace").Get() == "sRGB"
    disp = _shader(stage, "displacementTexture")
    d = a.maps["displacement"]
    assert disp.GetInput("scale").Get()[0] == pytest.approx(float(d.max() - d.min()), rel=1e-5)
    assert disp.GetInput("bias").Get()[0] == pytest.approx(float(d.min()), rel=1e-5)
    material = UsdShade.Material(stage.GetPrimAtPath("/face/mtl/material"))
    assert material.GetDisplacementOutput().HasConnectedSource()
    bound, _ = UsdShade.MaterialBindingAPI(mesh.GetPrim()).ComputeBoundMaterial()
    assert bound.GetPath() == material.GetPath()


def test_baked_displacement_moves_points_and_writes_no_texture(tmp_path):
    a = ict_asset()
    baked = Usd.Stage.Open(str(write_usd(a, tmp_path / "b.usdc", displacement="bake")))
    plain = Usd.Stage.Open(str(write_usd(a, tmp_path / "p.usdc", maps=["albedo", "normal"])))
    pb = np.array(UsdGeom.Mesh(baked.GetPrimAtPath("/face/mesh")).GetPointsAttr().Get())
    pp = np.array(UsdGeom.Mesh(plain.GetPrimAtPath("/face/mesh")).GetPointsAttr().Get())
    gap = np.linalg.norm(pb - pp, axis=1)
    assert 0.05 < gap.max() <= 0.41
    assert _shader(baked, "displacementTexture") is None
    assert not _surface(baked).GetInput("displacement")
    assert not (tmp_path / "b_textures" / "displacement.png").exists()


def test_only_what_the_scene_uses(tmp_path):
    """Constants become values, no texture nodes or st primvar without textures, map subsets."""
    maps = synthetic_maps(16)
    maps["roughness"] = np.full((16, 16), 0.37, np.float32)  # uniform: a factor
    a = ict_asset(maps={"albedo": maps["albedo"], "roughness": maps["roughness"]}, constants={"specular": 0.6})
    stage = Usd.Stage.Open(str(write_usd(a, tmp_path / "f.usda")))
    surface = _surface(stage)
    assert surface.GetInput("roughness").Get() == pytest.approx(0.37, abs=1e-6)
    assert tuple(surface.GetInput("specularColor").Get()) == pytest.approx((0.048,) * 3)
    assert _shader(stage, "roughnessTexture") is None and _shader(stage, "albedoTexture") is not None
    assert sorted(p.name for p in (tmp_path / "f_textures").iterdir()) == ["albedo.png"]
    assert validate_usd(tmp_path / "f.usda") == []

    constants_only = ict_asset(maps={}, constants={"albedo": (0.8, 0.6, 0.5), "roughness": 0.4})
    stage = Usd.Stage.Open(str(write_usd(constants_only, tmp_path / "c.usda")))
    mesh = stage.GetPrimAtPath("/face/mesh")
    assert UsdGeom.PrimvarsAPI(mesh).GetAuthoredPrimvars() == []
    assert _shader(stage, "stReader") is None
    diffuse = _surface(stage).GetInput("diffuseColor").Get()
    assert diffuse[0] == pytest.approx(((0.8 + 0.055) / 1.055) ** 2.4, rel=1e-5)  # linearised sRGB
    assert not _surface(stage).GetInput("useSpecularWorkflow")  # metallic workflow, ior 1.5: F0 0.04
    assert not (tmp_path / "c_textures").exists()
    assert validate_usd(tmp_path / "c.usda") == []

    subset = write_usd(ict_asset(), tmp_path / "s.usdz", maps=["albedo"])
    assert set(check_usd(subset).textures) == {"albedoTexture"}
    assert validate_usd(subset) == []


def test_flat_normal_map_is_dropped(tmp_path):
    flat = np.zeros((8, 8, 3), np.float32)
    flat[..., 2] = 1
    stage = Usd.Stage.Open(str(write_usd(ict_asset(maps={"normal": flat}), tmp_path / "n.usda")))
    assert _shader(stage, "normalTexture") is None and not _surface(stage).GetInput("normal")


def test_errors_leave_nothing(tmp_path):
    a = ict_asset(maps={"albedo": synthetic_maps(8)["albedo"]})
    with pytest.raises(InputError, match="maps"):
        write_usd(a, tmp_path / "x.usda", maps=["roughness"])
    with pytest.raises(InputError, match="suffix"):
        write_usd(a, tmp_path / "x.obj")
    with pytest.raises(InputError, match="displacement"):
        write_usd(a, tmp_path / "x.usda", displacement="none")
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(InputError):
        write_usd(a, blocker / "x.usda")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_export_asset_dispatch(tmp_path):
    a = ict_asset(size=16)
    assert export_asset(a, tmp_path / "a", format="usdz").name == "a.usdz"
    assert export_asset(a, tmp_path / "b.usdc").exists()
    with pytest.raises(InputError, match="suffix"):
        export_asset(a, tmp_path / "c.usda", format="usdz")
    with pytest.raises(InputError, match="glTF"):
        export_asset(a, tmp_path / "d.glb", displacement="texture")
    with pytest.raises(InputError, match="format"):
        export_asset(a, tmp_path / "e", format="fbx")


def test_degenerate_geometry_still_validates(tmp_path):
    from facegeo.asset import Asset
    from test_export_support import grid_mesh

    v, f, uv, ut = grid_mesh(4, 40.0)
    v = np.vstack([v, [[40.0, 0.0, 0.0], [50.0, 0.0, 0.0]]])
    f = np.vstack([f, [[25, 4, 26]]])
    uv = np.vstack([uv, [[0.99, 0.01], [0.99, 0.01]]])
    ut = np.vstack([ut, [[25, 4, 26]]])
    a = Asset(v, f, uv, ut, maps=synthetic_maps(16))
    for suffix in ("usda", "usdz"):
        path = write_usd(a, tmp_path / f"d.{suffix}", level=1)
        assert validate_usd(path) == []
        stage = Usd.Stage.Open(str(path))
        normals = np.array(UsdGeom.Mesh(stage.GetPrimAtPath("/face/mesh")).GetNormalsAttr().Get())
        assert np.isfinite(normals).all() and np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)


def test_sixteen_bit_linear_textures(tmp_path):
    from facegeo.image_files import read_png

    path = write_usd(ict_asset(size=16), tmp_path / "h.usda", linear_bits=16, displacement="texture")
    assert validate_usd(path) == []
    for name in ("normal", "roughness", "specular", "displacement"):
        assert read_png(str(tmp_path / "h_textures" / f"{name}.png")).dtype == np.uint16
    assert read_png(str(tmp_path / "h_textures" / "albedo.png")).dtype == np.uint8
    with pytest.raises(InputError, match="linear_bits"):
        write_usd(ict_asset(size=16), tmp_path / "x.usda", linear_bits=12)
