"""Renders of the real head scans with known cameras, poses and ground-truth albedo.

    python benchmarks/scan_renders.py [--scans james] [--samples 64]

renders every view of :data:`VIEWS` for each scan with Blender (Debian's ``blender``, Cycles on
the CPU; ``benchmarks/blender_render_scan.py``) into ``~/.cache/facegeo/scans/<scan>/renders/``;
a view whose files exist with the same recipe (view, samples, scan file, Blender script) is not
rendered again. Load one with :func:`load_view`::

    from scan_renders import load_view          # benchmarks/ on sys.path
    view = load_view("james", "yaw+20")
    view.image      # (H, W, 3) uint8 sRGB render (the photo a fitter gets: view.image_path)
    view.albedo     # (H, W, 3) uint8 sRGB: the texture's colour at each pixel, no shading
    view.mask       # (H, W) bool: the scan is seen at the pixel centre
    view.points     # (H, W, 3) float32 mm: the scan-space surface point at each pixel centre (NaN off the scan)
    view.camera     # facegeo.Camera: true focal (px) and principal point (px, pixel centres at +0.5)
    view.rotation, view.translation   # scan -> camera: X_c = R·X + t (mm), camera looks down −Z, +Y up
    view.light      # "soft" | "hard-side" (the views here; any light of blender_render_scan.LIGHTS for others)

Views (:data:`VIEWS`), all 512 × 768 px (portrait) except the crop: a 50 mm lens on a full-frame
camera (36 mm along the long side: focal 1066.7 px) at 600 mm from the face centre, under soft
even light (a uniform white environment), at yaw 0, ±20, ±40° and pitch ±15°; the frontal view
under a hard side light (a small sun from the subject's left, dim environment); a 135 mm lens
from 1700 mm (focal 2880 px); and ``crop``, a tight portrait crop of the frontal render
(principal point off-centre, image smaller, as users crop portraits; not rendered, cut from
``yaw+00``). Yaw and pitch follow :func:`facegeo.camera.rotation_from_euler` (yaw > 0 turns the
nose towards the viewer's right, pitch > 0 lowers the chin), applied after the scan's frontal
rotation :func:`frontal_rotation`, which turns the scan's 68 annotated landmarks (inner face)
onto the ICT-FaceKit mean shape's (rotation only): so the views' rotations are in the model's
canonical frame, up to the scan's own head posture.

The point maps come from ray casting the scan (open3d) through each pixel centre with the true
camera, not from Blender: exact, and the same convention as facegeo's pixels. Checked: a flat
100 mm square rendered through the same script lands where the true camera projects it (the
centroid of its albedo coverage within 0.07 px) and its albedo reads back the texture's value
(200/255 -> 201/255); on ``james`` ``yaw+00`` the albedo PNG matches a direct texture lookup
through the point map with a median difference of 2/255 per channel.
Public API: :data:`VIEWS`, :class:`ViewSpec`, :class:`ScanView`, :func:`render_views`,
:func:`load_view`, :func:`view_names`, :func:`frontal_rotation`, :func:`cast_rays`.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from head_scans import CACHE, SCANS, HeadScan, load_scan  # noqa: E402

from facegeo import Camera  # noqa: E402
from facegeo.camera import rotation_from_euler  # noqa: E402
from facegeo.errors import InputError  # noqa: E402
from facegeo.image_files import png_bytes, read_png  # noqa: E402
from facegeo.landmarks.scheme import INNER_FACE  # noqa: E402

__all__ = ["VIEWS", "ViewSpec", "ScanView", "render_views", "load_view", "view_names", "frontal_rotation",
           "cast_rays", "SENSOR_MM", "WIDTH", "HEIGHT"]

BLENDER_SCRIPT = Path(__file__).resolve().parent / "blender_render_scan.py"
#: Full-frame sensor, long side (mm); the renders are portrait, so it spans the height.
SENSOR_MM = 36.0
WIDTH, HEIGHT = 512, 768


@dataclass(frozen=True)
class ViewSpec:
    """One rendered view: yaw/pitch (degrees), lens (mm), distance of the face centre (mm), light."""

    name: str
    yaw: float = 0.0
    pitch: float = 0.0
    lens_mm: float = 50.0
    distance_mm: float = 600.0
    light: str = "soft"

    @property
    def focal_px(self) -> float:
        """The focal length in pixels (the sensor's long side spans the image's)."""
        return self.lens_mm / SENSOR_MM * max(WIDTH, HEIGHT)


VIEWS: tuple[ViewSpec, ...] = (
    ViewSpec("yaw+00"),
    ViewSpec("yaw-20", yaw=-20.0),
    ViewSpec("yaw+20", yaw=20.0),
    ViewSpec("yaw-40", yaw=-40.0),
    ViewSpec("yaw+40", yaw=40.0),
    ViewSpec("pitch-15", pitch=-15.0),
    ViewSpec("pitch+15", pitch=15.0),
    ViewSpec("hard-side", light="hard-side"),
    ViewSpec("tele-135", lens_mm=135.0, distance_mm=1700.0),
)
#: The crop view: cut from this rendered view.
CROP_OF = "yaw+00"


def view_names() -> list[str]:
    """Every view's name, the rendered ones then ``crop``."""
    return [v.name for v in VIEWS] + ["crop"]


@dataclass
class ScanView:
    """One view of a scan with its truth (see the module docstring for the fields)."""

    scan: str
    name: str
    image_path: Path
    albedo_path: Path
    camera: Camera
    rotation: np.ndarray
    translation: np.ndarray
    light: str
    lens_mm: float
    truth: dict

    @property
    def image(self) -> np.ndarray:
        """(H, W, 3) uint8 sRGB: the render."""
        return read_png(self.image_path)

    @property
    def albedo(self) -> np.ndarray:
        """(H, W, 3) uint8 sRGB: the ground-truth albedo (the texture's colour, unshaded; black off the scan)."""
        return read_png(self.albedo_path)

    def _points_file(self) -> dict[str, np.ndarray]:
        with np.load(self.image_path.with_name(self.name + "_points.npz")) as data:
            return {k: data[k] for k in data.files}

    @property
    def points(self) -> np.ndarray:
        """(H, W, 3) float32 mm: the scan-space surface point seen at each pixel centre (NaN: none)."""
        return self._points_file()["points"]

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: the scan is seen at the pixel centre."""
        return self._points_file()["triangle"] >= 0

    @property
    def triangle(self) -> np.ndarray:
        """(H, W) int32: the scan triangle seen at each pixel centre (−1: none)."""
        return self._points_file()["triangle"]


def _kabsch(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The rotation (3, 3) that best turns centred ``source`` (N, 3) onto centred ``target``."""
    a = source - source.mean(0)
    b = target - target.mean(0)
    u, _, vt = np.linalg.svd(b.T @ a)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    return u @ d @ vt


def frontal_rotation(scan: HeadScan) -> np.ndarray:
    """(3, 3) float64: turns the scan's inner-face landmarks (iBUG 17–67) onto the ICT-FaceKit
    mean shape's, so that the rotated scan faces +Z with +Y up (the model's frame)."""
    from facegeo import load_model

    if scan.annotation is None:
        raise InputError(scan.name, "annotation", "68 annotated landmarks to find the scan's frontal pose")
    model = load_model()
    target = model.mean_shape[model.landmark_indices[INNER_FACE]].astype(np.float64)
    return _kabsch(scan.annotation[INNER_FACE], target)


def face_centre(scan: HeadScan) -> np.ndarray:
    """(3,) mm: the mean of the inner-face landmarks, put on the optical axis in every view."""
    return scan.annotation[INNER_FACE].mean(0)


def view_pose(scan: HeadScan, spec: ViewSpec) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t (3,) mm) of the view: X_c = R·X + t with X in scan mm."""
    rotation = rotation_from_euler(spec.yaw, spec.pitch, 0.0) @ frontal_rotation(scan)
    translation = np.array([0.0, 0.0, -spec.distance_mm]) - rotation @ face_centre(scan)
    return rotation, translation


def cast_rays(vertices: np.ndarray, triangles: np.ndarray, rotation: np.ndarray, translation: np.ndarray,
              camera: Camera, pixels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's first hit through pixel positions: (points (..., 3) float32 mesh-space mm, NaN
    where the ray misses; triangle (...) int32, −1 where it misses).

    ``pixels``: (..., 2) continuous pixel positions (u right, v down); None: every pixel centre
    of the camera's image, giving (H, W, 3) and (H, W). The mesh is posed by X_c = R·X + t.
    """
    import open3d as o3d

    if pixels is None:
        u, v = np.meshgrid(np.arange(camera.width) + 0.5, np.arange(camera.height) + 0.5)
        pixels = np.stack([u, v], axis=-1)
    pixels = np.asarray(pixels, dtype=np.float64)
    shape = pixels.shape[:-1]
    uv = pixels.reshape(-1, 2)
    direction_cam = np.stack([(uv[:, 0] - camera.cx) / camera.focal, -(uv[:, 1] - camera.cy) / camera.focal,
                              -np.ones(len(uv))], axis=1)
    direction = direction_cam @ rotation  # Rᵀ·d for each row
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    origin = np.broadcast_to(-rotation.T @ translation, direction.shape)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(vertices, np.float32)), o3d.core.Tensor(np.asarray(triangles, np.uint32)))
    rays = o3d.core.Tensor(np.concatenate([origin, direction], axis=1).astype(np.float32))
    hit = scene.cast_rays(rays)
    distance = hit["t_hit"].numpy().astype(np.float64)
    triangle = hit["primitive_ids"].numpy().astype(np.int64)
    found = np.isfinite(distance)
    points = np.full((len(uv), 3), np.nan, dtype=np.float32)
    points[found] = (origin[found] + distance[found, None] * direction[found]).astype(np.float32)
    triangle = np.where(found, triangle, -1).astype(np.int32)
    return points.reshape(*shape, 3), triangle.reshape(shape)


def _recipe(scan: HeadScan, spec: ViewSpec, samples: int) -> str:
    text = json.dumps({"view": spec.__dict__, "samples": samples, "scan": scan.source.sha256, "scale": scan.source.scale_to_mm,
                       "size": [WIDTH, HEIGHT], "script": hashlib.sha256(BLENDER_SCRIPT.read_bytes()).hexdigest()},
                      sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _folder(scan_name: str, cache: Path) -> Path:
    return cache / scan_name / "renders"


def _done(folder: Path, name: str, recipe: str) -> bool:
    truth = folder / f"{name}.json"
    if not truth.exists():
        return False
    record = json.loads(truth.read_text())
    return record.get("recipe") == recipe and all((folder / record[k]).exists() for k in ("image", "albedo", "points"))


def _write_raw(folder: Path, scan: HeadScan) -> dict:
    vertices = scan.vertices.astype("<f4")
    triangles = scan.triangles.astype("<i4")
    corner_uv = scan.uv[scan.uv_triangles].astype("<f4")
    paths = {"vertices": folder / "mesh_vertices.f32", "triangles": folder / "mesh_triangles.i32",
             "corner_uv": folder / "mesh_corner_uv.f32"}
    for key, array in (("vertices", vertices), ("triangles", triangles), ("corner_uv", corner_uv)):
        array.tofile(paths[key])
    return {**{k: str(p) for k, p in paths.items()}, "n_vertices": len(vertices), "n_triangles": len(triangles)}


def _truth_record(scan: HeadScan, name: str, camera: Camera, rotation: np.ndarray, translation: np.ndarray,
                  light: str, lens_mm: float, recipe: str, extra: dict) -> dict:
    return {
        "scan": scan.name, "view": name, "recipe": recipe,
        "image": f"{name}.png", "albedo": f"{name}_albedo.png", "points": f"{name}_points.npz",
        "camera": camera.as_dict(), "rotation": rotation.tolist(), "translation_mm": translation.tolist(),
        "light": light, "lens_mm": lens_mm, "scale_to_mm": scan.source.scale_to_mm,
        "licence": scan.source.licence, "attribution": scan.source.attribution, **extra,
    }


def _save_points(folder: Path, name: str, points: np.ndarray, triangle: np.ndarray) -> None:
    np.savez_compressed(folder / f"{name}_points.npz", points=points, triangle=triangle)


def _crop_box(scan: HeadScan, spec: ViewSpec, camera: Camera) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) px of the tight, off-centre portrait crop of the frontal view: from a
    quarter of the face width left of the face to a tenth right of it, half the face height
    above the brows to a sixth below the chin."""
    from facegeo import project

    rotation, translation = view_pose(scan, spec)
    points = project(scan.annotation, rotation, translation, camera)
    (left, top), (right, bottom) = points.min(0), points.max(0)
    w, h = right - left, bottom - top
    x0, x1 = math.floor(left - 0.25 * w), math.ceil(right + 0.10 * w)
    y0, y1 = math.floor(top - 0.50 * h), math.ceil(bottom + 0.17 * h)
    return max(0, x0), max(0, y0), min(camera.width, x1), min(camera.height, y1)


def _make_crop(scan: HeadScan, folder: Path, recipe: str) -> None:
    spec = next(v for v in VIEWS if v.name == CROP_OF)
    base = load_view(scan.name, CROP_OF, cache=folder.parent.parent)
    x0, y0, x1, y1 = _crop_box(scan, spec, base.camera)
    camera = Camera(focal=base.camera.focal, cx=base.camera.cx - x0, cy=base.camera.cy - y0, width=x1 - x0, height=y1 - y0)
    (folder / "crop.png").write_bytes(png_bytes(base.image[y0:y1, x0:x1]))
    (folder / "crop_albedo.png").write_bytes(png_bytes(base.albedo[y0:y1, x0:x1]))
    points = base._points_file()
    _save_points(folder, "crop", points["points"][y0:y1, x0:x1], points["triangle"][y0:y1, x0:x1])
    record = _truth_record(scan, "crop", camera, base.rotation, base.translation, base.light, base.lens_mm, recipe,
                           {"crop_of": CROP_OF, "crop_box_px": [x0, y0, x1, y1]})
    (folder / "crop.json").write_text(json.dumps(record, indent=1))


def render_views(scan_name: str, samples: int = 64, cache: Path = CACHE, blender: str | None = None,
                 views: tuple[ViewSpec, ...] = VIEWS) -> Path:
    """Render every missing or outdated view of ``views`` (default :data:`VIEWS`, and then the
    crop) of the scan; returns the renders' folder."""
    scan = load_scan(scan_name, cache)
    folder = _folder(scan_name, cache)
    folder.mkdir(parents=True, exist_ok=True)
    todo = [spec for spec in views if not _done(folder, spec.name, _recipe(scan, spec, samples))]
    if todo:
        blender = blender or shutil.which("blender")
        if blender is None:
            raise InputError("blender", "executable", "Debian's blender on PATH (apt-get install -y blender)", "not found")
        jobs = []
        for spec in todo:
            rotation, translation = view_pose(scan, spec)
            matrix = np.eye(4)
            matrix[:3, :3] = rotation
            matrix[:3, 3] = translation * 0.001
            jobs.append({"name": spec.name, "matrix": matrix.ravel().tolist(), "lens_mm": spec.lens_mm,
                          "sensor_mm": SENSOR_MM, "width": WIDTH, "height": HEIGHT, "light": spec.light,
                          "image": str(folder / f"{spec.name}.png"), "albedo": str(folder / f"{spec.name}_albedo.png")})
        job = {"mesh": _write_raw(folder, scan), "texture": str(scan.texture), "samples": samples, "views": jobs}
        (folder / "job.json").write_text(json.dumps(job))
        with open(folder / "render.log", "w") as log:
            done = subprocess.run([blender, "-b", "--factory-startup", "-noaudio", "--python", str(BLENDER_SCRIPT), "--",
                                   str(folder / "job.json")], stdout=log, stderr=subprocess.STDOUT)
        if done.returncode != 0:
            raise RuntimeError(f"blender failed (exit {done.returncode}); see {folder / 'render.log'}")
        for spec in todo:
            if not (folder / f"{spec.name}.png").exists():
                raise RuntimeError(f"blender wrote no {spec.name}.png; see {folder / 'render.log'}")
            rotation, translation = view_pose(scan, spec)
            camera = Camera(focal=spec.focal_px, cx=WIDTH / 2, cy=HEIGHT / 2, width=WIDTH, height=HEIGHT)
            points, triangle = cast_rays(scan.vertices, scan.triangles, rotation, translation, camera)
            _save_points(folder, spec.name, points, triangle)
            record = _truth_record(scan, spec.name, camera, rotation, translation, spec.light, spec.lens_mm,
                                   _recipe(scan, spec, samples),
                                   {"yaw_deg": spec.yaw, "pitch_deg": spec.pitch, "distance_mm": spec.distance_mm,
                                    "samples": samples})
            (folder / f"{spec.name}.json").write_text(json.dumps(record, indent=1))
    crop_of = next((v for v in views if v.name == CROP_OF), None)
    if crop_of is not None and not _done(folder, "crop", crop_recipe := _recipe(scan, crop_of, samples) + "-crop"):
        _make_crop(scan, folder, crop_recipe)
    for stale in ("mesh_vertices.f32", "mesh_triangles.i32", "mesh_corner_uv.f32"):
        (folder / stale).unlink(missing_ok=True)
    return folder


def load_view(scan_name: str, view: str, cache: Path = CACHE) -> ScanView:
    """A rendered view with its truth (render it first with :func:`render_views`)."""
    folder = _folder(scan_name, cache)
    path = folder / f"{view}.json"
    if not path.exists():
        raise InputError(path, "view", f"a rendered view (python benchmarks/scan_renders.py --scans {scan_name})", "missing")
    record = json.loads(path.read_text())
    return ScanView(scan=scan_name, name=view, image_path=folder / record["image"], albedo_path=folder / record["albedo"],
                    camera=Camera(**record["camera"]), rotation=np.asarray(record["rotation"]),
                    translation=np.asarray(record["translation_mm"]), light=record["light"],
                    lens_mm=float(record["lens_mm"]), truth=record)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scans", nargs="+", default=list(SCANS), choices=list(SCANS))
    parser.add_argument("--samples", type=int, default=64,
                        help="Cycles samples per pixel (denoised where Blender has OpenImageDenoise; Debian's 3.4 has not)")
    args = parser.parse_args()
    for name in args.scans:
        folder = render_views(name, samples=args.samples)
        print(f"{name}: {folder}")


if __name__ == "__main__":
    main()
