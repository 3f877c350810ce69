"""Render a textured head scan with known cameras in Blender (Cycles, CPU); run by scan_renders.py.

    blender -b --factory-startup -noaudio --python benchmarks/blender_render_scan.py -- JOB.json

Runs inside Blender's own Python (Debian's blender 3.4 has no NumPy: plain lists and ``array``).
JOB.json holds ``mesh`` (paths of raw little-endian arrays: ``vertices`` float32 (V, 3) mm,
``triangles`` int32 (F, 3), ``corner_uv`` float32 (F, 3, 2)), ``texture`` (an sRGB image),
``samples``, and ``views``: each ``{"name", "matrix" (4 x 4 row-major, scan mm -> camera
metres: X_c = R·X·0.001 + t·0.001), "lens_mm", "sensor_mm" (along the long side), "width",
"height", "light" ("soft" | "hard-side" | "sun-sky"), "image", "albedo"}`` (output PNG paths).

Scene: the camera sits at the world origin with no rotation, so Blender's camera axes are
facegeo's (looking down −Z, +Y up) and world space is camera space (metres); the scan is placed
by the view's matrix. Lights are fixed in camera space: "soft" is a uniform white environment
(radiance 1: a fully open Lambertian point shows its albedo); "hard-side" is a dim environment
(0.06) and a small sun from the subject's left (the image's right), a little above and in front;
"sun-sky" is that sun warm (~4500 K) under a blue sky (an environment of 0.4, ~10000 K): the
shadowed skin is lit by a light of another colour than the lit skin, as outdoors.
Outputs per view: the render (8-bit sRGB, view transform Standard) and the Diffuse Color pass
(the texture's colour at each pixel, unshaded: the ground-truth albedo), both through the
compositor. A ``done`` list with the written files is printed as ``RENDERED <json>``.
"""

import array
import json
import math
import os
import sys

import bpy


def _read(path, code, count):
    values = array.array(code)
    with open(path, "rb") as f:
        values.fromfile(f, count)
    return values


def build_mesh(job):
    m = job["mesh"]
    n_v, n_f = m["n_vertices"], m["n_triangles"]
    vertices = _read(m["vertices"], "f", 3 * n_v)
    triangles = _read(m["triangles"], "i", 3 * n_f)
    corner_uv = _read(m["corner_uv"], "f", 6 * n_f)
    mesh = bpy.data.meshes.new("scan")
    mesh.vertices.add(n_v)
    mesh.vertices.foreach_set("co", array.array("f", (0.001 * v for v in vertices)))
    mesh.loops.add(3 * n_f)
    mesh.loops.foreach_set("vertex_index", triangles)
    mesh.polygons.add(n_f)
    mesh.polygons.foreach_set("loop_start", array.array("i", range(0, 3 * n_f, 3)))
    mesh.polygons.foreach_set("loop_total", array.array("i", [3]) * n_f)
    mesh.polygons.foreach_set("use_smooth", array.array("i", [1]) * n_f)
    uv_layer = mesh.uv_layers.new(name="UVMap")
    uv_layer.data.foreach_set("uv", corner_uv)
    mesh.update()
    mesh.validate()
    obj = bpy.data.objects.new("scan", mesh)
    bpy.context.scene.collection.objects.link(obj)

    material = bpy.data.materials.new("skin")
    material.use_nodes = True
    nodes = material.node_tree.nodes
    bsdf = nodes["Principled BSDF"]
    texture = nodes.new("ShaderNodeTexImage")
    texture.image = bpy.data.images.load(job["texture"])
    texture.image.colorspace_settings.name = "sRGB"
    material.node_tree.links.new(texture.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.5
    bsdf.inputs["Specular"].default_value = 0.35
    obj.data.materials.append(material)
    return obj


def set_up_scene(samples):
    scene = bpy.context.scene
    for obj in list(scene.objects):
        bpy.data.objects.remove(obj, do_unlink=True)
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.max_bounces = 4
    scene.cycles.seed = 1
    import _cycles

    # Debian's 3.4 build has no OpenImageDenoise: then no denoiser (more samples instead)
    scene.cycles.use_denoising = bool(getattr(_cycles, "with_openimagedenoise", False))
    if scene.cycles.use_denoising:
        scene.cycles.denoiser = "OPENIMAGEDENOISE"
    print("DENOISER", scene.cycles.use_denoising, flush=True)
    scene.render.film_transparent = False
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.display_settings.display_device = "sRGB"
    scene.view_layers[0].use_pass_diffuse_color = True

    camera_data = bpy.data.cameras.new("camera")
    camera_data.clip_start = 0.01
    camera_data.clip_end = 20.0
    camera = bpy.data.objects.new("camera", camera_data)
    scene.collection.objects.link(camera)
    scene.camera = camera

    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    scene.world = world

    sun_data = bpy.data.lights.new("sun", "SUN")
    sun_data.angle = math.radians(1.0)
    sun_data.energy = 5.0
    sun = bpy.data.objects.new("sun", sun_data)
    scene.collection.objects.link(sun)
    # from the subject's left (+X), above (+Y) and in front (+Z): the light travels along -direction
    direction = (0.82, 0.35, 0.45)
    norm = math.sqrt(sum(c * c for c in direction))
    d = [c / norm for c in direction]
    sun.rotation_mode = "QUATERNION"
    sun.rotation_quaternion = _quaternion_from_z(d)

    scene.use_nodes = True
    tree = scene.node_tree
    for node in list(tree.nodes):
        tree.nodes.remove(node)
    layers = tree.nodes.new("CompositorNodeRLayers")
    output = tree.nodes.new("CompositorNodeOutputFile")
    output.format.file_format = "PNG"
    output.format.color_mode = "RGB"
    output.format.color_depth = "8"
    output.file_slots.clear()
    output.file_slots.new("image_")
    output.file_slots.new("albedo_")
    tree.links.new(layers.outputs["Image"], output.inputs["image_"])
    tree.links.new(layers.outputs["DiffCol"], output.inputs["albedo_"])
    composite = tree.nodes.new("CompositorNodeComposite")
    tree.links.new(layers.outputs["Image"], composite.inputs["Image"])
    return scene, camera, world, sun, output


def _quaternion_from_z(d):
    """The rotation (w, x, y, z) taking the local +Z axis onto the unit vector ``d`` (a sun shines
    along its local −Z, so it then lights from direction ``d``)."""
    x, y, z = -d[1], d[0], 0.0  # axis = z × d
    s = math.sqrt(x * x + y * y)
    angle = math.acos(max(-1.0, min(1.0, d[2])))
    if s < 1e-12:
        return (1.0, 0.0, 0.0, 0.0)
    h = math.sin(angle / 2) / s
    return (math.cos(angle / 2), x * h, y * h, z * h)


#: Linear RGB (largest channel 1) of the "sun-sky" light's sun (~4500 K, luminance 0.84) and sky
#: (~10000 K, luminance 0.72).
SUN_COLOUR = (1.0, 0.81, 0.63)
SKY_COLOUR = (0.59, 0.73, 1.0)


def set_light(world, sun, light):
    background = world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    sun.data.color = (1.0, 1.0, 1.0)
    if light == "soft":
        background.inputs["Strength"].default_value = 1.0
        sun.hide_render = True
    elif light == "hard-side":
        background.inputs["Strength"].default_value = 0.06
        sun.hide_render = False
    elif light == "sun-sky":
        background.inputs["Color"].default_value = (*SKY_COLOUR, 1.0)
        background.inputs["Strength"].default_value = 0.4
        sun.data.color = SUN_COLOUR
        sun.hide_render = False
    else:
        raise ValueError(f"unknown light {light!r}")


def main():
    job = json.load(open(sys.argv[sys.argv.index("--") + 1]))
    scene, camera, world, sun, output = set_up_scene(job["samples"])
    obj = build_mesh(job)
    done = []
    for view in job["views"]:
        m = view["matrix"]
        from mathutils import Matrix

        obj.matrix_world = Matrix([m[0:4], m[4:8], m[8:12], m[12:16]])
        scene.render.resolution_x = view["width"]
        scene.render.resolution_y = view["height"]
        camera.data.lens = view["lens_mm"]
        camera.data.sensor_fit = "VERTICAL" if view["height"] >= view["width"] else "HORIZONTAL"
        camera.data.sensor_width = view["sensor_mm"]
        camera.data.sensor_height = view["sensor_mm"]
        set_light(world, sun, view["light"])
        folder = os.path.dirname(view["image"])
        output.base_path = folder
        output.file_slots[0].path = view["name"] + "__image_"
        output.file_slots[1].path = view["name"] + "__albedo_"
        scene.frame_set(1)
        bpy.ops.render.render(write_still=False)
        os.replace(os.path.join(folder, view["name"] + "__image_0001.png"), view["image"])
        os.replace(os.path.join(folder, view["name"] + "__albedo_0001.png"), view["albedo"])
        done.append(view["name"])
        print("VIEW", view["name"], flush=True)
    print("RENDERED " + json.dumps(done), flush=True)


main()
