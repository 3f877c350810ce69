"""Render a textured head scan with known cameras in Blender (Cycles, CPU); run by scan_renders.py.

    blender -b --factory-startup -noaudio --python benchmarks/blender_render_scan.py -- JOB.json

Runs inside Blender's own Python (Debian's blender 3.4 has no NumPy: plain lists and ``array``).
JOB.json holds ``mesh`` (paths of raw little-endian arrays: ``vertices`` float32 (V, 3) mm,
``triangles`` int32 (F, 3), ``corner_uv`` float32 (F, 3, 2)), ``texture`` (an sRGB image),
``samples``, and ``views``: each ``{"name", "matrix" (4 x 4 row-major, scan mm -> camera
metres: X_c = R·X·0.001 + t·0.001), "lens_mm", "sensor_mm" (along the long side), "width",
"height", "light" (a key of :data:`LIGHTS`), "image", "albedo"}`` (output PNG paths).

Scene: the camera sits at the world origin with no rotation, so Blender's camera axes are
facegeo's (looking down −Z, +Y up) and world space is camera space (metres); the scan is placed
by the view's matrix. Lights (:data:`LIGHTS`) are fixed in camera space: a uniform environment
and up to two sun lamps (parallel light, so the shading does not depend on the face's distance;
a sun's ``angle`` is its angular diameter: the larger, the softer its shadows). Directions are
towards the light, by azimuth (positive: the subject's left, the image's right, +X) and
elevation (positive: above) from the camera axis; a sun's energy is its irradiance (W/m²: a
Lambertian point facing it shows its albedo × energy / π), the environment's strength its
radiance (a fully open point shows its albedo × strength):

* "soft": a uniform white environment (strength 1), no sun;
* "hard-side": a small sun (1°, energy 5) from the subject's left, a little above and in front
  (direction (0.82, 0.35, 0.45): azimuth 61°, elevation 20°), and a dim environment (0.06);
* "sun-sky": that sun warm (~4500 K) under a blue sky (an environment of 0.4, ~10000 K): the
  shadowed skin is lit by a light of another colour than the lit skin, as outdoors;
* "key-fill": the studio portrait light: a large soft key (30°, energy 3) at azimuth 45°,
  elevation 30°, a fill of a third of its irradiance (30°, energy 1: the 3:1 ratio) from the
  other side (azimuth −45°, elevation 10°), and a dim environment (0.05);
* "window": one large soft source from the side (40°, energy 3.6) at azimuth 75°, elevation 15°,
  and a brighter environment (0.15) as the room's bounce;
* "ring": a ring light around the lens: a soft sun along the camera axis (18°, energy 3,
  direction (0, 0, 1)) and a dim environment (0.05).

Outputs per view: the render (8-bit sRGB, view transform Standard) and the Diffuse Color pass
(the texture's colour at each pixel, unshaded: the ground-truth albedo), both through the
compositor. A ``done`` list with the written files is printed as ``RENDERED <json>``.
"""

import array
import collections
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

    suns = []
    for name in ("sun", "fill"):
        sun = bpy.data.objects.new(name, bpy.data.lights.new(name, "SUN"))
        sun.rotation_mode = "QUATERNION"
        scene.collection.objects.link(sun)
        suns.append(sun)

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
    return scene, camera, world, suns, output


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


def _towards(azimuth_deg, elevation_deg):
    """The unit vector (camera space) towards a light at this azimuth (positive: the subject's
    left, +X) and elevation (positive: above, +Y) from the camera axis (+Z)."""
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return (math.sin(a) * math.cos(e), math.sin(e), math.cos(a) * math.cos(e))


#: Linear RGB (largest channel 1) of the "sun-sky" light's sun (~4500 K, luminance 0.84) and sky
#: (~10000 K, luminance 0.72).
SUN_COLOUR = (1.0, 0.81, 0.63)
SKY_COLOUR = (0.59, 0.73, 1.0)
WHITE = (1.0, 1.0, 1.0)
#: The small sun of "hard-side" and "sun-sky": from the subject's left (+X), above (+Y) and in
#: front (+Z); normalised where it is placed.
SIDE = (0.82, 0.35, 0.45)

#: A sun lamp: direction towards it (camera space), angular diameter (degrees), energy (W/m²), colour.
Sun = collections.namedtuple("Sun", "direction angle_deg energy colour")
#: A light: the environment's strength and colour, and its suns (at most two).
Light = collections.namedtuple("Light", "environment colour suns")
LIGHTS = {
    "soft": Light(1.0, WHITE, ()),
    "hard-side": Light(0.06, WHITE, (Sun(SIDE, 1.0, 5.0, WHITE),)),
    "sun-sky": Light(0.4, SKY_COLOUR, (Sun(SIDE, 1.0, 5.0, SUN_COLOUR),)),
    "key-fill": Light(0.05, WHITE, (Sun(_towards(45.0, 30.0), 30.0, 3.0, WHITE), Sun(_towards(-45.0, 10.0), 30.0, 1.0, WHITE))),
    "window": Light(0.15, WHITE, (Sun(_towards(75.0, 15.0), 40.0, 3.6, WHITE),)),
    "ring": Light(0.05, WHITE, (Sun((0.0, 0.0, 1.0), 18.0, 3.0, WHITE),)),
}


def set_light(world, suns, light):
    """Set the environment and the suns to the recipe :data:`LIGHTS` ``[light]``; unused suns are hidden."""
    if light not in LIGHTS:
        raise ValueError(f"unknown light {light!r}")
    recipe = LIGHTS[light]
    background = world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (*recipe.colour, 1.0)
    background.inputs["Strength"].default_value = recipe.environment
    for k, sun in enumerate(suns):
        sun.hide_render = k >= len(recipe.suns)
        if sun.hide_render:
            continue
        spec = recipe.suns[k]
        norm = math.sqrt(sum(c * c for c in spec.direction))
        sun.rotation_quaternion = _quaternion_from_z([c / norm for c in spec.direction])
        sun.data.angle = math.radians(spec.angle_deg)
        sun.data.energy = spec.energy
        sun.data.color = spec.colour


def main():
    job = json.load(open(sys.argv[sys.argv.index("--") + 1]))
    scene, camera, world, suns, output = set_up_scene(job["samples"])
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
        set_light(world, suns, view["light"])
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
