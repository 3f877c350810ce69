"""The glb opens in Blender with its textures bound (slow; needs Debian's ``blender`` package).

Run by hand::

    blender -b --factory-startup --python tests/blender/import_glb.py -- FACE.glb report.json
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from facegeo.export.gltf import write_glb
from test_export_support import ict_asset

SCRIPT = Path(__file__).resolve().parent / "blender" / "import_glb.py"


@pytest.fixture(scope="module")
def blender() -> str:
    """Debian's ``blender`` with the NumPy its glTF importer needs (Debian's Blender 3.4 runs the
    system Python 3.11), probed once for the module, else the tests are skipped with what to install."""
    blender = shutil.which("blender")
    if blender is None:
        pytest.skip("blender is not installed (apt-get install blender python3-numpy)")
    probe = subprocess.run([blender, "-b", "--factory-startup", "--python-exit-code", "1", "--python-expr", "import numpy"],
                           capture_output=True, text=True, timeout=300, check=False)
    if probe.returncode != 0:
        pytest.skip("blender's Python has no NumPy, which its glTF importer needs (apt-get install python3-numpy)")
    return blender


@pytest.mark.slow
def test_glb_imports_into_blender_with_textures_bound(tmp_path, blender):
    glb = write_glb(ict_asset(size=128), tmp_path / "face.glb", level=1)
    report_path = tmp_path / "report.json"
    result = subprocess.run([blender, "-b", "--factory-startup", "--python", str(SCRIPT), "--", str(glb), str(report_path)],
                            capture_output=True, text=True, timeout=600)
    assert report_path.is_file(), result.stdout[-2000:] + result.stderr[-2000:]
    report = json.loads(report_path.read_text())
    assert report["import"] == ["FINISHED"]
    (mesh,) = report["meshes"]
    assert mesh["faces"] == 4 * len(ict_asset(maps={}).triangles) and mesh["uv_layers"]
    assert 0.2 < max(mesh["dimensions"]) < 0.5  # metres: the head is about 34 cm tall
    (material,) = report["materials"].values()
    bound = {name: [t["image"] for t in textures] for name, textures in material.items() if isinstance(textures, list)}
    assert bound["Base Color"] == ["albedo"]
    assert bound["Roughness"] == ["metallicRoughness"]
    assert bound["Normal"] == ["normal"]
    assert bound.get("Specular"), "KHR_materials_specular did not reach the Principled BSDF"
    colourspaces = {t["image"]: t["colorspace"] for textures in material.values() if isinstance(textures, list) for t in textures}
    assert colourspaces["albedo"] == "sRGB" and colourspaces["normal"] == "Non-Color"
    assert all(t["has_data"] and t["size"][0] > 0 for textures in material.values() if isinstance(textures, list) for t in textures)


@pytest.mark.slow
def test_blender_imports_the_targets_as_shape_keys_and_jaw_open_opens_the_mouth(tmp_path, blender):
    """Blender 3.4 imports face.glb with one shape key per target, named as the file's
    targetNames; jawOpen = 1 drops the chin by more than 10 mm and moves the teeth and tongue."""
    import pygltflib

    from arkit_support import shaped_asset

    asset, model, alpha, _ = shaped_asset()
    glb = write_glb(asset, tmp_path / "face.glb")
    names = {m.name: (m.extras or {}).get("targetNames") for m in pygltflib.GLTF2().load_binary(str(glb)).meshes}
    chin = model.shape(alpha).numpy()[model.landmark_indices[8]] * 0.001  # iBUG 8 on the neutral mesh, metres
    report_path = tmp_path / "report.json"
    result = subprocess.run([blender, "-b", "--factory-startup", "--python", str(SCRIPT.parent / "shape_keys_glb.py"), "--",
                             str(glb), str(report_path), "jawOpen", *map(str, chin)], capture_output=True, text=True, timeout=600)
    assert report_path.is_file(), result.stdout[-2000:] + result.stderr[-2000:]
    report = json.loads(report_path.read_text())
    assert report["import"] == ["FINISHED"]
    meshes = report["meshes"]
    for name, targets in names.items():
        assert meshes[name]["shape_keys"] == ([] if targets is None else ["Basis", *targets]), name
    assert len(names["face"]) == 51
    chin_drop_mm = -meshes["face"]["point"]["displacement"][1] * 1000.0
    assert chin_drop_mm > 10.0, meshes["face"]["point"]
    for part in ("teeth", "gums_tongue"):
        assert meshes[part]["max_down"] * 1000.0 > 10.0, (part, meshes[part])
