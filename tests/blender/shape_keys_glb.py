"""Import a .glb into Blender (headless) and report its shape keys and what one of them does, as JSON.

    blender -b --factory-startup --python tests/blender/shape_keys_glb.py -- FILE.glb REPORT.json KEY X Y Z

For every mesh object: its shape key names (the basis first) and, with the shape key ``KEY`` set
to 1 (all others 0), the largest displacement of any vertex and its displacement downwards
(metres, in glTF's axes: +Y up), plus, for the object named ``face``, the displacement of the
vertex nearest to the glTF point (X, Y, Z) in metres. Positions are read from the evaluated
depsgraph (what Blender renders). Written for Debian's Blender 3.4 (see import_glb.py for its
``np.bool`` alias).
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


def evaluated_positions(obj):
    """(V, 3) world positions of the evaluated mesh, in glTF's axes (Blender is Z-up: x, z, -y)."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    evaluated.to_mesh_clear()
    world = np.array(obj.matrix_world)
    p = co.reshape(-1, 3) @ world[:3, :3].T + world[:3, 3]
    return np.stack([p[:, 0], p[:, 2], -p[:, 1]], axis=1)


def main():
    argv = sys.argv[sys.argv.index("--") + 1:]
    path, report_path, key = argv[0], argv[1], argv[2]
    point = np.array([float(x) for x in argv[3:6]])
    bpy.ops.wm.read_factory_settings(use_empty=True)
    result = bpy.ops.import_scene.gltf(filepath=path)
    report = {"import": list(result), "blender": bpy.app.version_string, "meshes": {}}
    for obj in bpy.data.objects:
        if obj.type != "MESH":
            continue
        keys = obj.data.shape_keys.key_blocks if obj.data.shape_keys else []
        entry = {"shape_keys": [k.name for k in keys], "vertices": len(obj.data.vertices)}
        if key in keys:
            for k in keys[1:]:
                k.value = 0.0
            rest = evaluated_positions(obj)
            keys[key].value = 1.0
            bpy.context.view_layer.update()
            moved = evaluated_positions(obj)
            keys[key].value = 0.0
            bpy.context.view_layer.update()
            delta = moved - rest
            entry["max_displacement"] = float(np.linalg.norm(delta, axis=1).max())
            entry["max_down"] = float(-delta[:, 1].min())
            if obj.name == "face":
                nearest = int(np.argmin(np.linalg.norm(rest - point, axis=1)))
                entry["point"] = {"rest": rest[nearest].tolist(), "displacement": delta[nearest].tolist()}
        report["meshes"][obj.name] = entry
    with open(report_path, "w") as fh:
        json.dump(report, fh, indent=1)


main()
