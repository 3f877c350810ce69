"""Import a .glb into Blender (headless) and report how its materials are bound, as JSON.

    blender -b --factory-startup --python tests/blender/import_glb.py -- FILE.glb REPORT.json

Written for Debian's Blender 3.4 (system Python): its glTF importer still uses ``np.bool``,
removed from NumPy 1.24, so the alias is restored before the importer loads. The report lists,
per material, the Principled BSDF inputs that are linked and the image textures reaching them
(name, size, colour space), and per mesh its vertex/face counts and UV layers.
"""

import json
import sys
import warnings

import numpy as np

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    if not hasattr(np, "bool"):
        np.bool = np.bool_  # Blender 3.4's io_import_scene_gltf2 uses the removed alias

import bpy  # noqa: E402


def upstream_images(socket, seen=None):
    """Image textures that feed ``socket`` through any chain of nodes."""
    seen = set() if seen is None else seen
    found = []
    for link in socket.links:
        node = link.from_node
        if node.name in seen:
            continue
        seen.add(node.name)
        if node.type == "TEX_IMAGE" and node.image is not None:
            img = node.image
            found.append({"node": node.name, "image": img.name, "size": list(img.size),
                          "colorspace": img.colorspace_settings.name, "has_data": bool(img.has_data or img.size[0] > 0)})
        for inp in node.inputs:
            found += upstream_images(inp, seen)
    return found


def main():
    argv = sys.argv[sys.argv.index("--") + 1:]
    path, report_path = argv[0], argv[1]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    result = bpy.ops.import_scene.gltf(filepath=path)
    report = {"import": list(result), "blender": bpy.app.version_string, "meshes": [], "materials": {}}
    for obj in bpy.data.objects:
        if obj.type != "MESH":
            continue
        me = obj.data
        report["meshes"].append({"name": obj.name, "vertices": len(me.vertices), "faces": len(me.polygons),
                                 "uv_layers": [uv.name for uv in me.uv_layers],
                                 "materials": [m.name for m in me.materials if m is not None],
                                 "dimensions": list(obj.dimensions)})
    for mat in bpy.data.materials:
        if not mat.use_nodes:
            continue
        entry = {}
        for node in mat.node_tree.nodes:
            if node.type != "BSDF_PRINCIPLED":
                continue
            for inp in node.inputs:
                if inp.is_linked:
                    entry[inp.name] = upstream_images(inp)
                elif inp.name in ("Roughness", "Metallic", "Specular"):
                    entry[inp.name + " value"] = float(inp.default_value)
        report["materials"][mat.name] = entry
    with open(report_path, "w") as fh:
        json.dump(report, fh, indent=1)


main()
