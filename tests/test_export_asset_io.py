"""Asset folders (save_asset / load_asset) and the ``facegeo export`` command."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from facegeo.errors import InputError
from facegeo.export.asset_io import load_asset, save_asset
from facegeo.mesh_io import OBJ_COMMENT, obj_text, read_obj
from facegeo.commands.arguments import add_commands
from facegeo.commands.export import COMMANDS
from facegeo.image_files import read_png
from facegeo.export.usd import check_usd, validate_usd
from test_export_support import ict_asset, synthetic_maps


def _run_cli(argv):
    parser = argparse.ArgumentParser(prog="facegeo")
    add_commands(parser.add_subparsers(dest="command", required=True), COMMANDS)
    args = parser.parse_args(argv)
    args.run(args)


def test_roundtrip_keeps_mesh_maps_constants_metadata(tmp_path):
    maps = synthetic_maps(32)
    del maps["specular"]
    a = ict_asset(maps=maps, constants={"specular": 0.45}, name="someone")
    a.metadata = {"fit": {"alpha": [0.1, -0.2]}, "timings": {"unwrap": 0.5}}
    folder = save_asset(a, tmp_path / "asset")
    doc = json.loads((folder / "asset.json").read_text())
    assert doc["maps"]["albedo"]["bits"] == 8 and doc["maps"]["albedo"]["colorspace"] == "srgb"
    assert doc["maps"]["displacement"]["bits"] == 16 and doc["maps"]["normal"]["scale"] == 2.0
    assert read_png(str(folder / "displacement.png")).dtype == np.uint16
    assert read_png(str(folder / "albedo.png")).dtype == np.uint8
    b = load_asset(folder)
    np.testing.assert_allclose(b.vertices, a.vertices, atol=1e-5)
    np.testing.assert_allclose(b.uv, a.uv, atol=1e-6)
    np.testing.assert_array_equal(b.triangles, a.triangles)
    np.testing.assert_array_equal(b.uv_triangles, a.uv_triangles)
    assert set(b.maps) == set(a.maps) and b.constants == {"specular": 0.45}
    assert b.name == "someone" and b.metadata == a.metadata
    np.testing.assert_allclose(b.maps["albedo"], a.maps["albedo"], atol=0.5 / 255 + 1e-6)
    for name in ("roughness",):
        np.testing.assert_allclose(b.maps[name], a.maps[name], atol=0.5 / 65535 + 1e-6)
    d = a.maps["displacement"]
    np.testing.assert_allclose(b.maps["displacement"], d, atol=0.5 * float(d.max() - d.min()) / 65535 + 1e-6)
    np.testing.assert_allclose(b.maps["normal"], a.maps["normal"], atol=1e-4)


def test_load_errors_name_file_and_field(tmp_path):
    with pytest.raises(InputError, match="no such folder"):
        load_asset(tmp_path / "missing")
    folder = save_asset(ict_asset(size=8), tmp_path / "a")
    (folder / "roughness.png").unlink()
    with pytest.raises(InputError, match="roughness.png"):
        load_asset(folder)
    (folder / "asset.json").write_text("{not json")
    with pytest.raises(InputError, match="asset.json"):
        load_asset(folder)
    (folder / "asset.json").write_text(json.dumps({"format": "facegeo-asset", "version": 99}))
    with pytest.raises(InputError, match="version"):
        load_asset(folder)
    folder2 = save_asset(ict_asset(size=8), tmp_path / "b")
    (folder2 / "albedo.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match="albedo.png"):
        load_asset(folder2)


def test_save_is_atomic_and_metadata_must_be_json(tmp_path):
    a = ict_asset(size=8)
    a.metadata = {"bad": object()}
    with pytest.raises(InputError, match="metadata"):
        save_asset(a, tmp_path / "out")
    assert not (tmp_path / "out").exists() and list(tmp_path.iterdir()) == []


def test_obj_text_is_what_savetxt_writes(model):
    """obj_text formats all rows in one operation; its text is byte for byte np.savetxt's (the
    model's mesh with its UVs, signed zeros, a point set, plain triangles)."""
    import io

    def savetxt(*blocks):
        out = io.StringIO()
        out.write(OBJ_COMMENT)
        for array, fmt in blocks:
            np.savetxt(out, array, fmt=fmt)
        return out.getvalue()

    v = model.mean_shape.astype(np.float64)
    v[:3] = [[-0.0, -1e-9, 0.0], [-2.4e-6, 1e6, -123.456785], [0.5, -0.5, 2.5]]
    t, uv, ut = model.triangles, model.uv, model.uv_triangles
    faces = np.stack([t + 1, ut + 1], axis=-1).reshape(-1, 6)
    assert obj_text(v, t, uv, ut) == savetxt((v, "v %.5f %.5f %.5f"), (uv, "vt %.6f %.6f"), (faces, "f %d/%d %d/%d %d/%d"))
    assert obj_text(v, t, digits=3) == savetxt((v, "v %.3f %.3f %.3f"), (t + 1, "f %d %d %d"))
    assert obj_text(v[:0]) == obj_text(np.zeros((0, 3))) == OBJ_COMMENT
    assert obj_text(v) == savetxt((v, "v %.5f %.5f %.5f"))


def test_read_obj_variants(tmp_path):
    p = tmp_path / "m.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\nf 1/1/1 2/2/1 3/3/1\nf -3/-3 -2/-2 -1/-1\n")
    v, f, uv, ut = read_obj(p)
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 1, 2]])
    np.testing.assert_array_equal(ut, f)
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n")
    with pytest.raises(InputError, match="triangle"):
        read_obj(p)


def test_cli_reexports_usdz_and_glb(tmp_path, capsys):
    folder = save_asset(ict_asset(size=32), tmp_path / "asset")
    _run_cli(["export", str(folder), "-o", str(tmp_path / "out" / "face"), "--format", "usdz,glb", "--subdiv", "1"])
    assert (tmp_path / "out" / "face.usdz").is_file() and (tmp_path / "out" / "face.glb").is_file()
    assert "wrote" in capsys.readouterr().out
    assert validate_usd(tmp_path / "out" / "face.usdz") == []
    _run_cli(["export", str(folder), "-o", str(tmp_path / "x.usda"), "--maps", "albedo,displacement", "--displacement", "texture"])
    assert set(check_usd(tmp_path / "x.usda").textures) == {"albedoTexture", "displacementTexture"}


def test_cli_errors(tmp_path):
    folder = save_asset(ict_asset(maps={"albedo": synthetic_maps(8)["albedo"]}), tmp_path / "asset")
    with pytest.raises(InputError, match="asset folder"):
        _run_cli(["export", str(tmp_path / "nope"), "-o", str(tmp_path / "f.glb")])
    with pytest.raises(InputError, match="--format"):
        _run_cli(["export", str(folder), "-o", str(tmp_path / "f"), "--format", "fbx"])
    with pytest.raises(InputError, match="displacement"):
        _run_cli(["export", str(folder), "-o", str(tmp_path / "f"), "--format", "usdz,glb", "--displacement", "texture"])
    with pytest.raises(InputError, match="maps"):
        _run_cli(["export", str(folder), "-o", str(tmp_path / "f.glb"), "--maps", "roughness"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["asset"]
