"""NoW-style geometric error of a predicted face mesh against a real head scan, and pose error.

The protocol (after NoW, Sanyal et al. 2019, adapted to renders with a known camera):

1. **Scan reference** (:func:`prepare_scan`): the scan surface is sampled densely and evenly
   (one point per ``sample_area_mm2`` of surface, area-weighted, fixed seed) and the samples
   within ``crop_radius_mm`` (95 mm) of the scan's nose tip (iBUG 30) and on its outer surface
   (:func:`outer_surface`: not enclosed, as a shell's inside is) are kept. The scan's 68
   iBUG landmarks give its face frame (:func:`face_frame`: +X towards the subject's left, +Y
   up, +Z forward) and its regions (:func:`region_of_samples`: forehead, nose, right/left
   cheek, mouth, chin, as polygons in the frontal (x, y) plane around the landmarks, front-facing
   surface only).
2. **Alignment** (:func:`align_to_scan`): the prediction's 7 keypoints (iBUG 36, 39, 42, 45,
   33, 48, 54: eye corners, nose base, mouth corners; the same seven as REALY) are
   similarity-aligned to the scan's (Umeyama, :func:`similarity_transform`), then rigid ICP
   (scale fixed after the landmark step, as NoW) moves the prediction so as to minimise the
   scan samples' distances to its surface (closest points on the triangles, libigl's AABB tree
   via :func:`facegeo.eval.realy_geometry.closest_points`).
3. **Error** (:func:`evaluate`): for every kept scan sample, the distance to the aligned
   prediction's surface (point to triangle, mm): median, mean, RMSE, 90th percentile, the mean
   per region; and the signed depth errors (mm, along the scan's forward axis +Z, prediction's
   front-most surface minus the scan's, both found by casting a ray along −Z) at the upper lip
   (iBUG 51), the lower lip (57) and the chin (pogonion: on the midline from 57 to 8, the scan's
   most forward point below the labiomental fold). Positive: the prediction sticks out further
   than the scan.

Pose (:func:`relative_rotation_error`): a fit's head rotation R_v of view v against the frontal
view's R_0 of the same scan: the relative rotation R_v·R_0ᵀ (camera frame), whose yaw, pitch and
roll (:func:`facegeo.camera.euler_from_rotation`) are compared with the true ones, and the angle
of the rotation between the two; neither the model's nor the scan's canonical frame enters.

Prediction interface (stable; used by ``bench_fit_scans.py`` and any fitter to compare):
:class:`Prediction` ``(vertices (V, 3) mm in any frame, triangles (F, 3), landmark_vertices (≥ 68,)
int vertex ids in iBUG order (the first 68 are read), rotation (3, 3) or None)``; a
:data:`ScanFitter` is ``fitter(image_path: Path, camera: Camera | None) -> Prediction`` (camera
None: the fitter's own default, i.e. the focal is not given).

Public API: :class:`Prediction`, :data:`ScanFitter`, :class:`ScanReference`, :func:`prepare_scan`,
:func:`face_frame`, :func:`region_of_samples`, :func:`sample_surface`, :func:`outer_surface`, :func:`similarity_transform`,
:func:`align_to_scan`, :func:`surface_distances`, :func:`evaluate`, :func:`relative_rotation_error`,
:data:`REGIONS`, :data:`KEYPOINTS`, :data:`DEPTH_PROBES`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from facegeo import Camera
from facegeo.camera import euler_from_rotation
from facegeo.eval.realy_geometry import closest_points
from facegeo.similarity_transform import similarity_transform

__all__ = ["Prediction", "ScanFitter", "ScanReference", "prepare_scan", "face_frame", "region_of_samples",
           "sample_surface", "outer_surface", "similarity_transform", "align_to_scan", "surface_distances", "evaluate",
           "relative_rotation_error", "REGIONS", "KEYPOINTS", "DEPTH_PROBES"]

#: The keypoints of the similarity step (iBUG-68 indices).
KEYPOINTS = (36, 39, 42, 45, 33, 48, 54)
#: Region names in report order; samples in none of them count only in the overall figures.
REGIONS = ("forehead", "nose", "right cheek", "left cheek", "mouth", "chin")


@dataclass
class Prediction:
    """A predicted face: vertices (V, 3) mm (any frame: it is aligned to the scan), triangles
    (F, 3) int, landmark_vertices (≥ 68,) int: vertex ids of the iBUG-68 points (88-point
    schemes: the first 68 are read), rotation (3, 3) float or None: the fitted head rotation
    (model -> camera, X_c = R·X + t) for the pose error."""

    vertices: np.ndarray
    triangles: np.ndarray
    landmark_vertices: np.ndarray
    rotation: np.ndarray | None = None
    info: dict = field(default_factory=dict)


#: ``fitter(image_path, camera)`` -> :class:`Prediction`; ``camera`` None: the fitter's default.
ScanFitter = Callable[[Path, Camera | None], Prediction]


@dataclass
class ScanReference:
    """A scan prepared for evaluation (all mm, scan frame).

    vertices (V, 3) float64, triangles (F, 3) int64, landmarks (68, 3) float64 (iBUG order),
    frame (3, 3): rows are the face frame's axes (:func:`face_frame`), samples (N, 3) float64:
    the surface samples within the crop, regions (N,) int8: index into :data:`REGIONS` or −1,
    depth_points (3, 2): the face-frame (x, y) of the upper lip, lower lip and chin probes.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    landmarks: np.ndarray
    frame: np.ndarray
    samples: np.ndarray
    regions: np.ndarray
    depth_points: np.ndarray
    crop_radius_mm: float


#: The depth probes' names, in the order of ``ScanReference.depth_points`` and ``evaluate(...)["depth"]``.
DEPTH_PROBES = ("upper lip", "lower lip", "chin")


def sample_surface(vertices: np.ndarray, triangles: np.ndarray, area_per_sample_mm2: float,
                   seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform random points on a triangle mesh: (points (N, 3) float64, triangle (N,) int64)
    with N = round(total area / ``area_per_sample_mm2``)."""
    v = np.asarray(vertices, dtype=np.float64)
    a, b, c = (v[triangles[:, k]] for k in range(3))
    areas = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    count = max(1, int(round(areas.sum() / area_per_sample_mm2)))
    rng = np.random.default_rng(seed)
    chosen = rng.choice(len(triangles), size=count, p=areas / areas.sum())
    r1, r2 = rng.random(count), rng.random(count)
    flip = r1 + r2 > 1.0
    r1[flip], r2[flip] = 1.0 - r1[flip], 1.0 - r2[flip]
    points = a[chosen] + r1[:, None] * (b[chosen] - a[chosen]) + r2[:, None] * (c[chosen] - a[chosen])
    return points, chosen


def face_frame(landmarks: np.ndarray) -> np.ndarray:
    """(3, 3) float64 whose rows are the face's axes from its 68 iBUG landmarks: X from the
    subject's right eye centre to the left one, Y up (eyes' midpoint minus the mouth centre,
    made orthogonal to X), Z = X × Y forward (out of the face)."""
    p = np.asarray(landmarks, dtype=np.float64)
    x = p[42:48].mean(0) - p[36:42].mean(0)
    x /= np.linalg.norm(x)
    y = 0.5 * (p[42:48].mean(0) + p[36:42].mean(0)) - p[48:60].mean(0)
    y -= x * (x @ y)
    y /= np.linalg.norm(y)
    return np.stack([x, y, np.cross(x, y)])


def _polygons(flat: np.ndarray) -> dict[str, np.ndarray]:
    """Region polygons in the face frame's (x, y) plane (mm) from the landmarks' (x, y) (68, 2)."""
    p = flat
    brow_top = p[17:27, 1].max()
    mouth_centre = p[48:60].mean(0)
    outer = p[48:60] + 6.0 * (p[48:60] - mouth_centre) / np.linalg.norm(p[48:60] - mouth_centre, axis=1, keepdims=True)
    below_lip = p[57, 1] - 5.0
    right_cheek = np.array([[p[36, 0], p[41, 1] - 8], [p[39, 0], p[40, 1] - 8], p[31] + [-4, 0], p[48] + [-3, 3],
                            p[4] + [8, 0], p[3] + [8, 0], p[2] + [8, 0], p[1] + [8, 0]])
    left_cheek = np.array([[p[45, 0], p[46, 1] - 8], [p[42, 0], p[47, 1] - 8], p[35] + [4, 0], p[54] + [3, 3],
                           p[12] + [-8, 0], p[13] + [-8, 0], p[14] + [-8, 0], p[15] + [-8, 0]])
    return {
        "forehead": np.array([[p[17, 0], brow_top + 8], [p[26, 0], brow_top + 8], [p[26, 0], brow_top + 53],
                              [p[17, 0], brow_top + 53]]),
        "nose": np.array([[p[27, 0] - 7, p[27, 1]], [p[27, 0] + 7, p[27, 1]], p[35] + [4, 0], p[33] + [0, -3],
                          p[31] + [-4, 0]]),
        "right cheek": right_cheek,
        "left cheek": left_cheek,
        "mouth": outer,
        "chin": np.array([[p[54, 0], below_lip], p[10], p[9], p[8], p[7], p[6], [p[48, 0], below_lip]]),
    }


def region_of_samples(points: np.ndarray, normals: np.ndarray, landmarks: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """(N,) int8: the index in :data:`REGIONS` of each point's region (−1: none). A point is in a
    region when its face-frame (x, y) lies in the region's polygon and its surface faces
    forward (normal's face-frame z > 0). Earlier regions in :data:`REGIONS` win overlaps."""
    from matplotlib.path import Path as PolygonPath

    local = (points - landmarks[30]) @ frame.T
    facing = (normals @ frame.T)[:, 2] > 0.0
    flat = (landmarks - landmarks[30]) @ frame.T
    out = np.full(len(points), -1, dtype=np.int8)
    for index, name in reversed(list(enumerate(REGIONS))):
        inside = PolygonPath(_polygons(flat[:, :2])[name]).contains_points(local[:, :2]) & facing
        out[inside] = index
    return out


def _raycasting_scene(vertices: np.ndarray, triangles: np.ndarray):
    """The mesh's open3d ray-casting scene (its BVH is built once, for every ray cast into it)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(vertices, np.float32)), o3d.core.Tensor(np.asarray(triangles, np.uint32)))
    return scene


def _first_hits(scene, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """(N,) float64: distance along each ray into :func:`_raycasting_scene`'s ``scene`` to the first hit (inf: none)."""
    import open3d as o3d

    rays = o3d.core.Tensor(np.concatenate([origins, directions], axis=1).astype(np.float32))
    return scene.cast_rays(rays)["t_hit"].numpy().astype(np.float64)


def _front_depth(vertices: np.ndarray, triangles: np.ndarray, frame: np.ndarray, origin: np.ndarray,
                 xy: np.ndarray) -> np.ndarray:
    """(N,) face-frame z (mm, relative to ``origin``) of the front-most surface at face-frame
    positions ``xy`` (N, 2), NaN where a ray along −Z misses."""
    start_z = 400.0
    local = np.column_stack([xy, np.full(len(xy), start_z)])
    origins = origin + local @ frame
    directions = np.broadcast_to(-frame[2], origins.shape)
    t = _first_hits(_raycasting_scene(vertices, triangles), origins, np.ascontiguousarray(directions))
    return np.where(np.isfinite(t), start_z - t, np.nan)


def outer_surface(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray, normals: np.ndarray,
                  directions: int = 64) -> np.ndarray:
    """(N,) bool: the surface points (N, 3) mm from which some ray escapes the mesh: of
    ``directions`` evenly spread over the hemisphere about each point's normal (N, 3) (or its
    opposite: triangle winding is not trusted), one that hits nothing. A scan's inner surfaces
    (the inside of a shell, a mouth bag) are enclosed and fail; the outer skin, nostrils and ear
    folds included, passes."""
    k = np.arange(directions) + 0.5
    z = 1.0 - k / directions  # a Fibonacci hemisphere about +Z
    phi = np.pi * (3.0 - np.sqrt(5.0)) * k
    local = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], axis=1)
    scene = _raycasting_scene(vertices, triangles)
    free = np.zeros(len(points), bool)
    for sign in (1.0, -1.0):
        n = sign * normals
        helper = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
        u = np.cross(n, helper)
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        v = np.cross(n, u)
        for d in local:
            todo = ~free
            if not todo.any():
                return free
            ray = d[0] * u[todo] + d[1] * v[todo] + d[2] * n[todo]
            t = _first_hits(scene, points[todo] + 0.05 * ray, ray)
            free[np.flatnonzero(todo)[~np.isfinite(t)]] = True
    return free


def prepare_scan(vertices: np.ndarray, triangles: np.ndarray, landmarks: np.ndarray, crop_radius_mm: float = 95.0,
                 area_per_sample_mm2: float = 2.0, seed: int = 0) -> ScanReference:
    """The scan's samples within ``crop_radius_mm`` of its nose tip (iBUG 30) on its outer
    surface, their regions and the depth probes (see the module docstring). ``landmarks``:
    (68, 3) mm on the scan, iBUG order."""
    vertices = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64)
    landmarks = np.asarray(landmarks, dtype=np.float64)[:68]
    frame = face_frame(landmarks)
    points, tri = sample_surface(vertices, triangles, area_per_sample_mm2, seed)
    keep = np.linalg.norm(points - landmarks[30], axis=1) <= crop_radius_mm
    points, tri = points[keep], tri[keep]
    a, b, c = (vertices[triangles[tri, k]] for k in range(3))
    normals = np.cross(b - a, c - a)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    outer = outer_surface(vertices, triangles, points, normals)  # a scan's inner surfaces are not its face
    points, normals = points[outer], normals[outer]
    regions = region_of_samples(points, normals, landmarks, frame)
    flat = (landmarks - landmarks[30]) @ frame.T
    # chin probe (pogonion): on the midline segment from the lower lip (57) to the chin (8), the
    # scan's most forward point below the deepest point of the upper 60 % (the labiomental fold)
    segment = flat[57, :2][None] + np.linspace(0.0, 1.0, 41)[:, None] * (flat[8, :2] - flat[57, :2])[None]
    depth = _front_depth(vertices, triangles, frame, landmarks[30], segment)
    depth = np.where(np.isfinite(depth), depth, -np.inf)
    fold = int(np.argmin(np.where(np.arange(41) <= 24, depth, np.inf)))
    chin = segment[fold + int(np.argmax(depth[fold:]))] if np.isfinite(depth[fold:]).any() else flat[8, :2]
    probes = np.stack([flat[51, :2], flat[57, :2], chin])
    return ScanReference(vertices=vertices, triangles=triangles, landmarks=landmarks, frame=frame, samples=points,
                         regions=regions, depth_points=probes, crop_radius_mm=crop_radius_mm)


def surface_distances(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distances (N,) mm, closest points (N, 3)) from ``points`` to the mesh's surface."""
    closest = closest_points(np.asarray(vertices, np.float64), np.asarray(triangles, np.int64), np.asarray(points, np.float64))
    return np.linalg.norm(closest - points, axis=1), closest


def align_to_scan(prediction: Prediction, reference: ScanReference, iterations: int = 100,
                  tolerance_mm: float = 1e-4) -> tuple[np.ndarray, dict]:
    """The prediction's vertices (V, 3) float64 in the scan frame: 7-keypoint similarity, then
    rigid ICP (scale fixed) of the prediction's surface to the scan samples, until the RMS
    distance falls by less than ``tolerance_mm`` in a step. Returns them and
    ``{"scale", "icp_iterations", "keypoint_rms_mm"}``."""
    ids = np.asarray(prediction.landmark_vertices)[list(KEYPOINTS)]
    vertices = np.asarray(prediction.vertices, dtype=np.float64)
    scale, rotation, translation = similarity_transform(vertices[ids], reference.landmarks[list(KEYPOINTS)])
    aligned = scale * vertices @ rotation.T + translation
    keypoint_rms = float(np.sqrt(((aligned[ids] - reference.landmarks[list(KEYPOINTS)]) ** 2).sum(1).mean()))
    previous = math.inf
    done = 0
    for done in range(1, iterations + 1):  # the RMS distance never grows from one step to the next
        distance, closest = surface_distances(aligned, prediction.triangles, reference.samples)
        current = float(np.sqrt((distance ** 2).mean()))
        if previous - current < tolerance_mm:
            break
        _, r, t = similarity_transform(closest, reference.samples, with_scale=False)
        aligned = aligned @ r.T + t
        previous = current
    return aligned, {"scale": scale, "icp_iterations": done, "keypoint_rms_mm": keypoint_rms}


def evaluate(prediction: Prediction, reference: ScanReference) -> dict:
    """The NoW-style errors (mm) of ``prediction`` against the scan (module docstring):
    ``median``, ``mean``, ``rmse``, ``p90``, ``regions`` {name: mean}, ``depth`` {probe: signed
    mm}, ``n_samples`` and the alignment's ``alignment`` record."""
    aligned, alignment = align_to_scan(prediction, reference)
    distance, _ = surface_distances(aligned, prediction.triangles, reference.samples)
    regions = {name: float(distance[reference.regions == k].mean()) if np.any(reference.regions == k) else math.nan
               for k, name in enumerate(REGIONS)}
    origin = reference.landmarks[30]
    scan_z = _front_depth(reference.vertices, reference.triangles, reference.frame, origin, reference.depth_points)
    pred_z = _front_depth(aligned, prediction.triangles, reference.frame, origin, reference.depth_points)
    depth = {name: float(pred_z[k] - scan_z[k]) for k, name in enumerate(DEPTH_PROBES)}
    return {
        "median": float(np.median(distance)),
        "mean": float(distance.mean()),
        "rmse": float(np.sqrt((distance ** 2).mean())),
        "p90": float(np.percentile(distance, 90)),
        "regions": regions,
        "depth": depth,
        "n_samples": int(len(distance)),
        "alignment": alignment,
    }


def _wrap(degrees: float) -> float:
    return (degrees + 180.0) % 360.0 - 180.0


def relative_rotation_error(fit_view: np.ndarray, fit_frontal: np.ndarray, true_view: np.ndarray,
                            true_frontal: np.ndarray) -> dict[str, float]:
    """Errors (degrees) of the fitted relative rotation R_v·R_0ᵀ against the true one:
    ``yaw``, ``pitch``, ``roll`` (fitted minus true Euler angles of the relative rotations,
    :func:`facegeo.camera.euler_from_rotation`, wrapped to [−180, 180)) and ``angle`` (the
    angle of the rotation taking the true relative rotation to the fitted one)."""
    fitted = np.asarray(fit_view, np.float64) @ np.asarray(fit_frontal, np.float64).T
    true = np.asarray(true_view, np.float64) @ np.asarray(true_frontal, np.float64).T
    f, t = euler_from_rotation(fitted), euler_from_rotation(true)
    cos = (np.trace(fitted @ true.T) - 1.0) / 2.0
    return {"yaw": _wrap(f[0] - t[0]), "pitch": _wrap(f[1] - t[1]), "roll": _wrap(f[2] - t[2]),
            "angle": math.degrees(math.acos(max(-1.0, min(1.0, cos))))}
