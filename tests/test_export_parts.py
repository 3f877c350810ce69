"""Parts in the asset folder, USD and glTF, and ``--parts face|head|full``."""

from __future__ import annotations

import numpy as np
import pygltflib
import pytest

from facegeo.asset import Asset
from facegeo.cli import main
from facegeo.errors import InputError
from facegeo.export.asset_io import load_asset, save_asset
from facegeo.export.gltf import GltfValidatorMissing, find_gltf_validator, validate_glb, write_glb
from facegeo.export.usd import check_usd, validate_usd, write_usd
from facegeo.parts import load_parts, part_assets
from test_export_support import ict_asset, model

PART_NAMES = ["eyeballs", "eye_sockets", "mouth_socket", "gums_tongue", "teeth"]


@pytest.fixture(scope="module")
def asset_with_parts() -> Asset:
    m = model()
    asset = ict_asset(size=32)
    asset.parts = part_assets(load_parts(m), m, None, None, iris_srgb=(0.2, 0.4, 0.6), texture_size=32)
    asset.face_triangles = np.all(m.face_mask[m.triangles], axis=1)
    asset.validate()
    return asset


@pytest.fixture(scope="module")
def saved(tmp_path_factory, asset_with_parts):
    folder = tmp_path_factory.mktemp("asset") / "a"
    save_asset(asset_with_parts, folder)
    return folder


def test_asset_folder_round_trip(saved, asset_with_parts):
    back = load_asset(saved)
    assert [p.name for p in back.parts] == PART_NAMES
    np.testing.assert_array_equal(back.face_triangles, asset_with_parts.face_triangles)
    for mine, theirs in zip(asset_with_parts.parts, back.parts):
        np.testing.assert_allclose(theirs.vertices, mine.vertices, atol=1e-4)
        np.testing.assert_array_equal(theirs.triangles, mine.triangles)
        assert set(theirs.maps) == set(mine.maps) and set(theirs.constants) == set(mine.constants)
        for name, value in mine.constants.items():
            np.testing.assert_allclose(theirs.constants[name], value)
    np.testing.assert_allclose(back.parts[0].maps["albedo"], asset_with_parts.parts[0].maps["albedo"], atol=0.5 / 255 + 1e-6)


@pytest.mark.parametrize("suffix", [".usda", ".usdz"])
def test_usd_has_a_prim_and_bound_material_per_part(tmp_path, asset_with_parts, suffix):
    path = write_usd(asset_with_parts, tmp_path / f"face{suffix}")
    check = check_usd(path)
    assert check.mesh_path == "/face/mesh" and check.material_path == "/face/mtl/material"
    assert check.parts == {f"/face/parts/{n}": f"/face/mtl/{n}" for n in PART_NAMES}
    assert set(check.part_textures) == {"eyeballs/albedoTexture"}  # the others are constants
    assert [e for e in validate_usd(path) if e[0] == "Error"] == []
    from pxr import Usd, UsdGeom, UsdShade

    stage = Usd.Stage.Open(str(path))
    teeth = UsdGeom.Mesh(stage.GetPrimAtPath("/face/parts/teeth"))
    assert len(teeth.GetPointsAttr().Get()) == len(asset_with_parts.parts[-1].vertices)
    surface = UsdShade.Material(stage.GetPrimAtPath("/face/mtl/teeth")).ComputeSurfaceSource()[0]
    assert surface.GetInput("roughness").Get() == pytest.approx(0.25)


def test_glb_has_a_mesh_and_material_per_part(tmp_path, asset_with_parts):
    path = write_glb(asset_with_parts, tmp_path / "face.glb")
    doc = pygltflib.GLTF2().load_binary(str(path))
    assert [m.name for m in doc.meshes] == ["face", *PART_NAMES]
    assert [m.name for m in doc.materials] == [f"{n}_material" for n in ["face", *PART_NAMES]]
    assert [p.material for m in doc.meshes for p in m.primitives] == list(range(6))
    assert doc.scenes[0].nodes == list(range(6))
    eye = doc.materials[1]
    assert eye.pbrMetallicRoughness.baseColorTexture is not None and doc.meshes[1].primitives[0].attributes.TEXCOORD_0 is not None
    teeth = doc.materials[5].pbrMetallicRoughness
    assert teeth.baseColorTexture is None and teeth.roughnessFactor == pytest.approx(0.25)
    try:
        find_gltf_validator()
    except GltfValidatorMissing as exc:
        pytest.skip(f"Khronos glTF-Validator not available: {exc}")
    issues = validate_glb(path)["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]


def test_select(asset_with_parts):
    full = asset_with_parts.select("full")
    assert full is asset_with_parts
    head = asset_with_parts.select("head")
    assert head.parts == [] and len(head.triangles) == len(asset_with_parts.triangles)
    face = asset_with_parts.select("face")
    n_face = int(asset_with_parts.face_triangles.sum())
    assert face.parts == [] and len(face.triangles) == n_face
    assert len(face.vertices) == len(np.unique(asset_with_parts.triangles[asset_with_parts.face_triangles]))
    # the kept triangles are the same triangles in space, with their UVs
    np.testing.assert_array_equal(face.vertices[face.triangles], asset_with_parts.vertices[asset_with_parts.triangles[asset_with_parts.face_triangles]])
    np.testing.assert_array_equal(face.uv[face.uv_triangles], asset_with_parts.uv[asset_with_parts.uv_triangles[asset_with_parts.face_triangles]])
    with pytest.raises(InputError, match="parts"):
        asset_with_parts.select("torso")


@pytest.mark.parametrize("choice, meshes", [("face", 1), ("head", 1), ("full", 6)])
def test_export_command_parts(tmp_path, saved, asset_with_parts, capsys, choice, meshes):
    out = tmp_path / "x.glb"
    assert main(["export", str(saved), "-o", str(out), "--parts", choice, "--maps", "albedo"]) == 0, capsys.readouterr().err
    doc = pygltflib.GLTF2().load_binary(str(out))
    assert len(doc.meshes) == meshes
    n_triangles = doc.accessors[doc.meshes[0].primitives[0].indices].count // 3
    expected = int(asset_with_parts.face_triangles.sum()) if choice == "face" else len(asset_with_parts.triangles)
    assert n_triangles == expected


def test_export_command_rejects_an_unknown_choice(tmp_path, saved, capsys):
    with pytest.raises(SystemExit):
        main(["export", str(saved), "-o", str(tmp_path / "x.glb"), "--parts", "torso"])
    assert "--parts" in capsys.readouterr().err
