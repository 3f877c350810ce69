"""glTF 2.0 binary export (facegeo.export.gltf): Khronos validator, conventions, tangents."""

from __future__ import annotations

import io

import numpy as np
import pygltflib
import pytest
import trimesh

from facegeo.errors import InputError
from facegeo.normals import vertex_normals
from facegeo.export.gltf import GltfValidatorMissing, find_gltf_validator, validate_glb, write_glb
from test_export_support import ict_asset, synthetic_maps

_ACCESSOR_DTYPES = {5126: np.float32, 5125: np.uint32, 5123: np.uint16}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def _require_validator():
    try:
        find_gltf_validator()
    except GltfValidatorMissing as exc:
        pytest.skip(f"Khronos glTF-Validator not available: {exc}")


def _read(path):
    doc = pygltflib.GLTF2().load_binary(str(path))
    blob = doc.binary_blob()

    def accessor(index):
        acc = doc.accessors[index]
        view = doc.bufferViews[acc.bufferView]
        data = np.frombuffer(blob, dtype=_ACCESSOR_DTYPES[acc.componentType], count=acc.count * _WIDTH[acc.type],
                             offset=view.byteOffset + (acc.byteOffset or 0))
        return data.reshape(acc.count, -1) if _WIDTH[acc.type] > 1 else data

    return doc, accessor


CASES = {
    "all maps, level 0": dict(level=0),
    "all maps, level 1": dict(level=1),
    "albedo only, level 2": dict(level=2, maps=["albedo"]),
    "normal and roughness": dict(level=0, maps=["normal", "roughness"]),
    "specular and displacement": dict(level=1, maps=["specular", "displacement"]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_khronos_validator_zero_errors_zero_warnings(tmp_path, case):
    _require_validator()
    path = write_glb(ict_asset(), tmp_path / "face.glb", **CASES[case])
    issues = validate_glb(path)["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]


def test_khronos_validator_constants_only(tmp_path):
    _require_validator()
    a = ict_asset(maps={}, constants={"albedo": (0.7, 0.5, 0.4), "roughness": 0.45, "specular": 0.5, "displacement": 0.2})
    path = write_glb(a, tmp_path / "c.glb")
    issues = validate_glb(path)["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]


def test_validator_catches_a_broken_file(tmp_path):
    _require_validator()
    path = write_glb(ict_asset(maps={}), tmp_path / "f.glb")
    data = bytearray(path.read_bytes())
    data[12 + 8:12 + 8 + 9] = b'{"bogus":'  # corrupt the JSON chunk
    bad = tmp_path / "bad.glb"
    bad.write_bytes(bytes(data))
    assert validate_glb(bad)["issues"]["numErrors"] > 0


def test_conventions_metres_flipped_v_and_material(tmp_path):
    a = ict_asset()
    path = write_glb(a, tmp_path / "face.glb", maps=["albedo", "normal", "roughness", "specular"])
    doc, accessor = _read(path)
    prim = doc.meshes[0].primitives[0]
    pos = accessor(prim.attributes.POSITION)
    uv = accessor(prim.attributes.TEXCOORD_0)
    idx = accessor(prim.indices).reshape(-1, 3)
    # each output vertex is a (vertex, UV) wedge of the asset, in metres, v flipped
    np.testing.assert_allclose(pos.min(axis=0), a.vertices.min(axis=0) * 0.001, atol=1e-7)
    np.testing.assert_allclose(pos[idx].reshape(-1, 3), a.vertices[a.triangles].reshape(-1, 3) * 0.001, atol=1e-7)
    np.testing.assert_allclose(uv[idx].reshape(-1, 2), np.stack([a.uv[a.uv_triangles][..., 0], 1 - a.uv[a.uv_triangles][..., 1]], -1).reshape(-1, 2), atol=1e-6)
    normals = accessor(prim.attributes.NORMAL)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    mat = doc.materials[0]
    pbr = mat.pbrMetallicRoughness
    assert pbr.metallicFactor == 0.0 and pbr.roughnessFactor == 1.0
    assert pbr.baseColorTexture is not None and pbr.metallicRoughnessTexture is not None and mat.normalTexture is not None
    spec = mat.extensions["KHR_materials_specular"]
    assert spec["specularColorFactor"] == [2.0, 2.0, 2.0] and "specularColorTexture" in spec
    assert doc.extensionsUsed == ["KHR_materials_specular"]
    assert mat.alphaCutoff is None


def test_tangents_are_mikktspace_of_the_written_mesh(tmp_path):
    """TANGENT equals facegeo.uv's MikkTSpace (the texture stage's frame) on the written
    geometry and normals, and B = w (N x T) points along +v of the Asset's UVs (up in the image)."""
    from facegeo.uv.tangents import mesh_tangents

    a = ict_asset()
    path = write_glb(a, tmp_path / "face.glb", maps=["normal"])
    doc, accessor = _read(path)
    prim = doc.meshes[0].primitives[0]
    tan = accessor(prim.attributes.TANGENT)
    idx = accessor(prim.indices).reshape(-1, 3)
    pos = accessor(prim.attributes.POSITION).astype(np.float64)
    nrm = accessor(prim.attributes.NORMAL).astype(np.float64)
    uv = accessor(prim.attributes.TEXCOORD_0).astype(np.float64)
    uv[:, 1] = 1 - uv[:, 1]  # back to the Asset's v-up UVs
    np.testing.assert_allclose(np.linalg.norm(tan[:, :3], axis=1), 1.0, atol=1e-5)
    assert set(np.unique(tan[:, 3])) <= {-1.0, 1.0}
    expected = mesh_tangents(a.vertices, a.triangles, a.uv, a.uv_triangles, vertex_normals(a.vertices, a.triangles).astype(np.float32))
    np.testing.assert_allclose(tan[idx], expected, atol=1e-5)
    # the frame against the UV gradients of each triangle
    p, t = pos[idx], uv[idx]
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    s1, s2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    det = s1[:, 0] * s2[:, 1] - s1[:, 1] * s2[:, 0]
    dpdu = (d1 * s2[:, 1:2] - d2 * s1[:, 1:2]) / det[:, None]
    dpdv = (d2 * s1[:, 0:1] - d1 * s2[:, 0:1]) / det[:, None]
    corner_t = tan[idx[:, 0]]
    bitangent = np.cross(nrm[idx[:, 0]], corner_t[:, :3]) * corner_t[:, 3:4]
    assert np.mean(np.sum(corner_t[:, :3] * dpdu, axis=1) > 0) > 0.99
    assert np.mean(np.sum(bitangent * dpdv, axis=1) > 0) > 0.99


def test_only_what_the_scene_uses(tmp_path):
    a = ict_asset(maps={}, constants={"albedo": (0.7, 0.5, 0.4), "roughness": 0.45})
    doc, _ = _read(write_glb(a, tmp_path / "c.glb"))
    prim = doc.meshes[0].primitives[0]
    assert prim.attributes.TEXCOORD_0 is None and prim.attributes.TANGENT is None
    assert doc.textures == [] and doc.images == [] and doc.samplers == []
    assert doc.materials[0].extensions in ({}, None) and not doc.extensionsUsed
    assert doc.materials[0].pbrMetallicRoughness.roughnessFactor == pytest.approx(0.45)
    assert doc.materials[0].pbrMetallicRoughness.baseColorFactor[0] == pytest.approx(((0.7 + 0.055) / 1.055) ** 2.4, rel=1e-5)

    albedo_only = ict_asset(maps={"albedo": synthetic_maps(8)["albedo"]}, constants={"specular": 0.25})
    doc, _ = _read(write_glb(albedo_only, tmp_path / "a.glb"))
    prim = doc.meshes[0].primitives[0]
    assert prim.attributes.TEXCOORD_0 is not None and prim.attributes.TANGENT is None
    assert len(doc.images) == 1
    assert doc.materials[0].extensions["KHR_materials_specular"] == {"specularColorFactor": [0.5, 0.5, 0.5]}
    assert doc.materials[0].pbrMetallicRoughness.roughnessFactor == 0.5  # written: glTF's default is 1


def test_displacement_is_baked(tmp_path):
    a = ict_asset()
    doc, accessor = _read(write_glb(a, tmp_path / "b.glb", maps=["displacement"]))
    assert doc.images == []
    prim = doc.meshes[0].primitives[0]
    pos = accessor(prim.attributes.POSITION)
    assert len(pos) == len(a.vertices)  # no texture, so no UVs: one vertex per geometry vertex
    gap_mm = np.linalg.norm(pos * 1000.0 - a.vertices, axis=1)
    assert 0.05 < gap_mm.max() <= 0.41  # the synthetic map's amplitude is 0.4 mm
    loaded = trimesh.load(io.BytesIO((tmp_path / "b.glb").read_bytes()), file_type="glb", force="mesh")
    assert len(loaded.faces) == len(a.triangles)


def test_bad_arguments(tmp_path):
    a = ict_asset(maps={})
    with pytest.raises(InputError, match="glb"):
        write_glb(a, tmp_path / "x.gltf")
    with pytest.raises(InputError, match="maps"):
        write_glb(a, tmp_path / "x.glb", maps=["albedo"])
    assert list(tmp_path.iterdir()) == []


def test_degenerate_geometry_still_validates(tmp_path):
    """A zero-area triangle, a vertex only in it (no normal of its own) and a triangle with zero
    UV area: normals and tangents stay unit length, so the validator still reports nothing."""
    from facegeo.asset import Asset
    from test_export_support import grid_mesh

    v, f, uv, ut = grid_mesh(4, 40.0)
    v = np.vstack([v, [[40.0, 0.0, 0.0], [50.0, 0.0, 0.0], [60.0, 0.0, 0.0]]])
    f = np.vstack([f, [[25, 4, 26], [9, 4, 25]]])  # 25, 26 only in degenerate / zero-UV triangles
    uv = np.vstack([uv, [[0.99, 0.01], [0.99, 0.01], [0.99, 0.01]]])
    ut = np.vstack([ut, [[25, 4, 26], [26, 27, 25]]])
    maps = synthetic_maps(16)
    a = Asset(v, f, uv, ut, maps=maps)
    for level in (0, 1):
        path = write_glb(a, tmp_path / f"d{level}.glb", level=level)
        doc, accessor = _read(path)
        prim = doc.meshes[0].primitives[0]
        for attr in (prim.attributes.NORMAL, prim.attributes.TANGENT):
            vec = accessor(attr)[:, :3]
            assert np.isfinite(vec).all()
            np.testing.assert_allclose(np.linalg.norm(vec, axis=1), 1.0, atol=1e-5)
    try:
        find_gltf_validator()
    except GltfValidatorMissing:
        return
    for level in (0, 1):
        issues = validate_glb(tmp_path / f"d{level}.glb")["issues"]
        assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]


@pytest.mark.parametrize("guess", [("albedo", "normal", "roughness", "specular"), ("albedo",), ()])
def test_arrays_made_before_the_maps_give_the_same_file(monkeypatch, guess):
    # facegeo reconstruct makes the glTF arrays on the geometry while the texture stages run: the
    # file is the same bytes whether the guess at the skin's maps was right (the arrays are then
    # not made again) or wrong (they are made for the written material)
    import dataclasses

    import facegeo.export.gltf as gltf
    from facegeo.export.scene import scene_geometries, scene_surfaces

    asset = ict_asset({name: m for name, m in synthetic_maps().items() if name != "displacement"})  # nothing to bake
    expected = gltf.glb_bytes(asset, level=1)
    geometries = scene_geometries(dataclasses.replace(asset, maps={}, constants={}), level=1)
    gltf.prepare_surface_arrays(geometries, [], guess)
    right = set(guess) == set(asset.maps)
    if right:
        monkeypatch.setattr(gltf, "_with_tangents", lambda *args: pytest.fail("tangents made again"))
    assert gltf.glb_bytes(asset, level=1, surfaces=scene_surfaces(asset, level=1, geometries=geometries)) == expected
