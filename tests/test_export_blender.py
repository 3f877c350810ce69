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


@pytest.mark.slow
def test_glb_imports_into_blender_with_textures_bound(tmp_path):
    blender = shutil.which("blender")
    if blender is None:
        pytest.skip("blender is not installed (apt-get install blender python3-numpy)")
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
