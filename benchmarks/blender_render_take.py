"""Render an animated face.glb (``facegeo animate``'s) frame by frame in Blender (Cycles, CPU); run by
bench_track_truth.py.

    blender -b --factory-startup -noaudio -t 1 --python benchmarks/blender_render_take.py -- JOB.json

Runs inside Blender's own Python. JOB.json holds ``glb`` (the animated file), ``fps`` (the
scene's rate: the glTF importer keys a time of t seconds at frame t × fps, so the take's row k
is frame k), ``frames`` ([first, last], inclusive), ``width``/``height`` (px), ``focal_px``,
``camera_mm`` (the camera's centre in the model's axes, mm: +X the subject's left, +Y up, +Z out
of the face; it looks along −Z with +Y up, unrotated, so a fit's model-to-camera rotation is the
head node's rotation), ``light`` (a key of ``blender_render_scan.LIGHTS``, fixed in camera space
as there), ``samples`` (Cycles samples a pixel; the noise seed changes every frame, like a
camera's sensor noise), ``out`` (a folder: ``frame_00000.png``, ... by frame number) and
``probe`` (a JSON path).

Frames already in ``out`` are not rendered again (an interrupted render resumes). Before
rendering, every frame is evaluated and ``probe`` gets, per frame, the face mesh's shape-key
values (name -> value) and the head node's world rotation in the model's axes (3 × 3, row-major)
as Blender sees them: what the benchmark compares with the take it animated the file with. Each
frame rendered prints ``FRAME k seconds``; the end ``RENDERED <count>``.

The lights, and the helpers that place them, are ``blender_render_scan.py``'s (read from that
file without running its ``main``); the suns are children of the camera, so their directions are
in camera space as in that script. Blender 3.4's glTF importer calls ``numpy.bool`` and other
aliases that NumPy 1.24 removed; they are put back (as the builtins they stood for) before the
import.
"""

import ast
import json
import math
import os
import sys
import time

import bpy
import numpy
from mathutils import Matrix, Vector

#: glTF / model axes (+Y up, +Z out of the face) -> Blender's (+Z up): (x, y, z) -> (x, −z, y).
GLTF_TO_BLENDER = Matrix(((1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0)))


def scan_lights():
    """``blender_render_scan.py``'s top-level definitions (``LIGHTS``, ``set_light``, ...), its
    final ``main()`` call left out."""
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "blender_render_scan.py")
    tree = ast.parse(open(path).read(), path)
    tree.body = [node for node in tree.body
                 if not (isinstance(node, ast.Expr) and isinstance(node.value, ast.Call)
                         and getattr(node.value.func, "id", None) == "main")]
    namespace = {"__name__": "blender_render_scan", "__file__": path}
    exec(compile(tree, path, "exec"), namespace)
    return namespace


def restore_numpy_aliases():
    """The aliases (``numpy.bool`` ...) Blender 3.4's glTF importer still uses."""
    for name, builtin in (("bool", bool), ("int", int), ("float", float), ("object", object)):
        if name not in numpy.__dict__:
            setattr(numpy, name, builtin)


def set_up_scene(job, scan):
    """An empty scene: Cycles on the CPU, the camera, the world and two suns parented to it."""
    scene = bpy.context.scene
    for obj in list(scene.objects):
        bpy.data.objects.remove(obj, do_unlink=True)
    scene.render.fps = int(job["fps"])
    scene.render.fps_base = int(job["fps"]) / job["fps"]
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = job["samples"]
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.max_bounces = 4
    scene.cycles.seed = 1
    scene.cycles.use_animated_seed = True
    scene.cycles.use_denoising = False
    scene.render.use_persistent_data = True
    scene.render.film_transparent = False
    scene.render.resolution_x = job["width"]
    scene.render.resolution_y = job["height"]
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.color_depth = "8"
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.display_settings.display_device = "sRGB"

    camera_data = bpy.data.cameras.new("camera")
    camera_data.clip_start = 0.01
    camera_data.clip_end = 20.0
    camera_data.sensor_fit = "HORIZONTAL"
    camera_data.sensor_width = 36.0
    camera_data.lens = job["focal_px"] * 36.0 / job["width"]
    camera = bpy.data.objects.new("camera", camera_data)
    scene.collection.objects.link(camera)
    scene.camera = camera
    camera.location = GLTF_TO_BLENDER @ Vector([0.001 * c for c in job["camera_mm"]])
    camera.rotation_mode = "XYZ"
    camera.rotation_euler = (math.pi / 2, 0.0, 0.0)  # looks along Blender's +Y (the model's −Z), up +Z (the model's +Y)

    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    scene.world = world
    suns = []
    for name in ("sun", "fill"):
        sun = bpy.data.objects.new(name, bpy.data.lights.new(name, "SUN"))
        sun.rotation_mode = "QUATERNION"
        sun.parent = camera
        scene.collection.objects.link(sun)
        suns.append(sun)
    scan["set_light"](world, suns, job["light"])
    return scene


def import_take(path):
    """Import the glb; return the face mesh object (the one whose shape keys the take drives) and the head node."""
    restore_numpy_aliases()
    bpy.ops.import_scene.gltf(filepath=path)
    head = bpy.data.objects["head"]
    face = bpy.data.objects["face"]
    if face.data.shape_keys is None or face.data.shape_keys.animation_data is None:
        raise SystemExit(f"{path}: the face mesh has no animated shape keys")
    if head.animation_data is None or head.animation_data.action is None:
        raise SystemExit(f"{path}: the head node has no active animation")
    return face, head


def write_probe(scene, face, head, first, last, path):
    """Per frame: the face's shape-key values and the head's rotation in the model's axes."""
    keys = [k for k in face.data.shape_keys.key_blocks if k.name != face.data.shape_keys.reference_key.name]
    back = GLTF_TO_BLENDER.transposed()
    frames = []
    for frame in range(first, last + 1):
        scene.frame_set(frame)
        rotation = back @ head.matrix_world.to_3x3().normalized() @ GLTF_TO_BLENDER
        frames.append({"frame": frame, "weights": {k.name: k.value for k in keys},
                       "head_rotation": [v for row in rotation for v in row]})
    with open(path, "w") as handle:
        json.dump({"frames": frames}, handle)


def main():
    job = json.load(open(sys.argv[sys.argv.index("--") + 1]))
    scan = scan_lights()
    scene = set_up_scene(job, scan)
    face, head = import_take(job["glb"])
    first, last = job["frames"]
    scene.frame_start, scene.frame_end = first, last
    write_probe(scene, face, head, first, last, job["probe"])
    os.makedirs(job["out"], exist_ok=True)
    rendered = 0
    for frame in range(first, last + 1):
        target = os.path.join(job["out"], f"frame_{frame:05d}.png")
        if os.path.exists(target):
            continue
        start = time.perf_counter()
        scene.frame_set(frame)
        scene.render.filepath = target + ".part.png"
        bpy.ops.render.render(write_still=True)
        os.replace(target + ".part.png", target)
        rendered += 1
        print(f"FRAME {frame} {time.perf_counter() - start:.2f}", flush=True)
    print(f"RENDERED {rendered}", flush=True)


main()
