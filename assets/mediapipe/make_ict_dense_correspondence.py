"""Make ``ict_dense_correspondence.npz``: MediaPipe's 468 face-mesh points on the ICT-FaceKit skin.

Sources (both Apache-2.0, MediaPipe authors), downloaded into a temporary folder and checked
against the sha256 values below:

* the ``mediapipe==0.10.14`` wheel (``extract_mediapipe_models.download_wheel``, the same wheel
  the bundled ``.tflite`` files come from): ``mediapipe/python/solutions/face_mesh_connections.py``
  gives the named point sets (face oval, lips, eyes, brows, nose) and the tesselation;
* the npm package ``@mediapipe/face_mesh@0.4.1657299874`` (``npm pack``): the wheel carries no
  canonical face mesh, this package does, as
  ``/third_party/mediapipe/modules/face_geometry/data/geometry_pipeline_metadata_landmarks.binarypb``
  inside ``face_mesh_solution_packed_assets.data`` (offsets in
  ``face_mesh_solution_packed_assets_loader.js``): MediaPipe's canonical face model (468 vertices,
  cm, +Y up, +Z out of the face), the mesh its face-geometry pipeline fits to the 468 landmarks by
  index. Its edges are checked against the wheel's ``FACEMESH_TESSELATION`` (the same points,
  triangulated alike but for the mouth and some flipped quads), and its vertex order against the
  detector (the bundled ``face_landmark.tflite``) on the bundled
  astronaut photo and on renders.

Steps:

1. **Registration** (:func:`facegeo.landmarks.dense.register_canonical_mesh`): rigid + scale from
   the iBUG-68 pairs (inner face and chin), non-rigid ICP (trimesh's ``nricp_amberg``) onto ICT's
   mean face, closest points on ICT's face region: the *prior* (triangle, barycentric) per point.
2. **Renders**: random ICT faces (identity α ~ N(0, 0.5²), sparse expressions, skin tone, SH
   light and framing from :func:`facegeo.regressor.synthetic.random_face`; yaw ±30°, pitch ±15°,
   roll ±8°) drawn with the eyeballs (iris texture), eye and mouth sockets, gums and teeth of
   ``ict_face_parts.npz``, lips and brows painted, by facegeo's z-buffer rasteriser; MediaPipe's
   mesh (:class:`~facegeo.landmarks.mediapipe_mesh.MediaPipeFaceMesh`) run on each. Two sets with
   different seeds: one to refine, one held out to measure.
3. **Refinement**: per point, among the surface samples of ICT's face region within
   :data:`SEARCH_RADIUS_MM` of the prior (mean shape), the one whose projections into the refining
   renders are closest to the detections (mean of squared distances, each capped at
   :data:`ROBUST_CAP_MM`, converted to mm by the render's inter-ocular distance, plus
   :data:`PRIOR_WEIGHT` × the squared distance from the prior). The point moves there only when the
   detector consistently disagrees with the prior: the new point must be nearer the detection in
   at least :data:`CONSISTENCY` of the renders; otherwise it keeps the prior.
4. **Transfer error**: per point, the RMS over the held-out renders of the distance between the
   detected and the projected point, in mm at the point's depth (pixels × depth / focal), floored
   at :data:`ERROR_FLOOR_MM`. ``prior_error_mm`` is the same for the prior: the error to expect
   from the registration alone (what :func:`facegeo.landmarks.dense.load_dense_correspondence`
   gives other models).

Renders of model faces are not real faces: the prior stays unless the detector disagrees with it
consistently, and the errors measured here are a lower bound of those on photos.

Usage (about 10 minutes on 2 cores; prints the tables of ``README.md``)::

    python assets/mediapipe/make_ict_dense_correspondence.py [--out DIR] [--wheel WHL] [--npm-tarball TGZ]
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import json
import re
import struct
import subprocess
import tarfile
import tempfile
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from matplotlib.path import Path as Polygon
from scipy.spatial import cKDTree

from extract_mediapipe_models import WHEEL_NAME, WHEEL_SHA256, download_wheel, sha256_of
from facegeo.assets import asset_path
from facegeo.camera import Camera, rotation_from_euler, to_pixels
from facegeo.colour import linear_to_srgb, srgb_to_linear
from facegeo.landmarks.dense import (
    DENSE_ASSET,
    DENSE_FORMAT_VERSION,
    register_canonical_mesh,
    triangles_sha256,
)
from facegeo.landmarks.mediapipe_mesh import N_MESH, MediaPipeFaceMesh
from facegeo.landmarks.scheme import OUTER_EYE_CORNERS
from facegeo.lighting import sh_irradiance
from facegeo.model_files import load_model
from facegeo.morphable_model import MorphableModel
from facegeo.similarity_transform import similarity_transform
from facegeo.normals import vertex_normals
from facegeo.parts import PART_MATERIALS, PartModel, eyeball_texture, load_parts, part_vertices
from facegeo.regressor.network import ModelSignature
from facegeo.regressor.synthetic import random_face
from facegeo.skin_mask import FACE_OVAL, LEFT_BROW, RIGHT_BROW, vertex_regions
from facegeo.staged_output import StagedOutput
from facegeo.uv.renderer import rasterize_mesh
from facegeo.uv.texels import sample_uv

NPM_PACKAGE = "@mediapipe/face_mesh"
NPM_VERSION = "0.4.1657299874"
NPM_TARBALL = f"mediapipe-face_mesh-{NPM_VERSION}.tgz"
NPM_SHA256 = "c08a7e0742a326285da666cf81d77c8b6f3a181a2ee948cadaf166008e0d3bc7"
PACKED_ASSETS = "package/face_mesh_solution_packed_assets.data"
PACKED_TABLE = "package/face_mesh_solution_packed_assets_loader.js"
GEOMETRY_FILE = "/third_party/mediapipe/modules/face_geometry/data/geometry_pipeline_metadata_landmarks.binarypb"
GEOMETRY_SHA256 = "bdbcda96dfcb7da883da124aaa2c55dee49770d934f0fcc71747f8c21bdc75b4"
CONNECTIONS_MEMBER = "mediapipe/python/solutions/face_mesh_connections.py"
CONNECTION_SETS = ("FACEMESH_FACE_OVAL", "FACEMESH_LIPS", "FACEMESH_LEFT_EYE", "FACEMESH_RIGHT_EYE",
                   "FACEMESH_LEFT_EYEBROW", "FACEMESH_RIGHT_EYEBROW", "FACEMESH_NOSE", "FACEMESH_TESSELATION")

#: Render size (px) and the number of renders that refine / that measure (different seeds).
RENDER_SIZE = 320
REFINE_RENDERS, HELD_OUT_RENDERS = 160, 80
REFINE_SEED, HELD_OUT_SEED = 1, 2
#: Identity σ (in the model's σ units), expression probability, pose ranges (degrees).
SIGMA_ID, EXPRESSIONS = 0.5, 0.05
MAX_YAW, MAX_PITCH, MAX_ROLL = 30.0, 15.0, 8.0

#: Refinement: search radius around the prior (mm, mean shape), the cap of each render's error
#: (mm), the weight of the squared distance from the prior (mm² per mm²), the fraction of renders
#: in which the refined point must beat the prior, the surface sampling (points per triangle edge).
SEARCH_RADIUS_MM = 12.0
FINE_RADIUS_MM = 3.0
ROBUST_CAP_MM = 8.0
PRIOR_WEIGHT = 0.2
CONSISTENCY = 2.0 / 3.0
SAMPLES_PER_EDGE = 5
#: Floor of the transfer error (mm): no point is trusted to better than this.
ERROR_FLOOR_MM = 1.0

#: Regions of the report, in priority order (a point belongs to the first set that has it).
REGIONS = (("contour", ("FACEMESH_FACE_OVAL",)), ("lips", ("FACEMESH_LIPS",)),
           ("eyes", ("FACEMESH_LEFT_EYE", "FACEMESH_RIGHT_EYE")),
           ("brows", ("FACEMESH_LEFT_EYEBROW", "FACEMESH_RIGHT_EYEBROW")), ("nose", ("FACEMESH_NOSE",)))
OTHER_REGION = "cheeks, forehead, chin"


# -------------------------------------------------------------------------------------- sources


def download_npm_package(folder: Path) -> Path:
    """``npm pack`` the pinned package into ``folder`` and return the tarball's path."""
    subprocess.run(["npm", "pack", f"{NPM_PACKAGE}@{NPM_VERSION}", "--pack-destination", str(folder)],
                   check=True, stdout=subprocess.DEVNULL)
    tarball = folder / NPM_TARBALL
    if not tarball.is_file():
        raise SystemExit(f"expected {NPM_TARBALL} after npm pack, found {sorted(p.name for p in folder.iterdir())}")
    return tarball


def _varint(data: bytes, at: int) -> tuple[int, int]:
    value, shift = 0, 0
    while True:
        byte = data[at]
        at += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            return value, at


def protobuf_fields(data: bytes) -> list[tuple[int, int, int | bytes]]:
    """The (field number, wire type, value) of a serialized protobuf message, in order: varints as
    int, fixed32/fixed64 and length-delimited values as bytes (the protobuf wire format; enough
    for the two MediaPipe messages read here, without their generated classes)."""
    fields, at = [], 0
    while at < len(data):
        key, at = _varint(data, at)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, at = _varint(data, at)
        elif wire in (1, 5):
            size = 8 if wire == 1 else 4
            value, at = data[at:at + size], at + size
        elif wire == 2:
            size, at = _varint(data, at)
            value, at = data[at:at + size], at + size
        else:
            raise SystemExit(f"{GEOMETRY_FILE}: unsupported protobuf wire type {wire}")
        fields.append((number, wire, value))
    return fields


def canonical_face_mesh(tarball: Path) -> tuple[np.ndarray, np.ndarray]:
    """MediaPipe's canonical face mesh from the npm package: (468, 3) float32 cm and (F, 3) int64.

    ``GeometryPipelineMetadata.canonical_mesh`` (field 1) is a ``Mesh3d``: ``vertex_type`` 1
    (0 = VERTEX_PT: x, y, z, u, v per vertex), ``primitive_type`` 2 (0 = TRIANGLE),
    ``vertex_buffer`` 3 (floats), ``index_buffer`` 4 (uint32), repeated fields packed or not.
    """
    with tarfile.open(tarball) as archive:
        packed = archive.extractfile(PACKED_ASSETS).read()
        table = archive.extractfile(PACKED_TABLE).read().decode()
    entry = re.search(r'\{"filename": "' + re.escape(GEOMETRY_FILE) + r'", "start": (\d+), "end": (\d+)\}', table)
    if entry is None:
        raise SystemExit(f"{tarball.name}:{PACKED_TABLE}: no entry for {GEOMETRY_FILE}")
    blob = packed[int(entry.group(1)):int(entry.group(2))]
    if hashlib.sha256(blob).hexdigest() != GEOMETRY_SHA256:
        raise SystemExit(f"{GEOMETRY_FILE}: sha256 {hashlib.sha256(blob).hexdigest()}, expected {GEOMETRY_SHA256}")
    mesh = [v for n, w, v in protobuf_fields(blob) if n == 1]
    floats: list[float] = []
    indices: list[int] = []
    kinds = {}
    for number, wire, value in protobuf_fields(mesh[0]):
        if number in (1, 2):
            kinds[number] = value
        elif number == 3:
            floats.extend(struct.unpack(f"<{len(value) // 4}f", value))
        elif number == 4 and wire == 0:
            indices.append(value)
        elif number == 4:
            at = 0
            while at < len(value):
                index, at = _varint(value, at)
                indices.append(index)
    if kinds.get(1, 0) != 0 or kinds.get(2, 0) != 0 or len(floats) != 5 * N_MESH:
        raise SystemExit(f"{GEOMETRY_FILE}: expected {N_MESH} VERTEX_PT vertices as triangles, found {kinds}, {len(floats)} floats")
    vertices = np.asarray(floats, np.float32).reshape(N_MESH, 5)[:, :3]
    return vertices, np.asarray(indices, np.int64).reshape(-1, 3)


def connection_sets(wheel: Path) -> dict[str, set[int]]:
    """The wheel's named face-mesh connection sets as sets of point indices (read as data: the
    literal lists of ``face_mesh_connections.py``; nothing of it is run) and, under
    ``"edges"``, the tesselation's edges as sorted pairs."""
    with zipfile.ZipFile(wheel) as archive:
        tree = ast.parse(archive.read(CONNECTIONS_MEMBER).decode())
    found: dict[str, list[tuple[int, int]]] = {}
    for node in tree.body:
        if (isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)
                and node.targets[0].id in CONNECTION_SETS and isinstance(node.value, ast.Call) and node.value.args):
            found[node.targets[0].id] = ast.literal_eval(node.value.args[0])
    missing = set(CONNECTION_SETS) - set(found)
    if missing:
        raise SystemExit(f"{wheel.name}:{CONNECTIONS_MEMBER}: no literal {sorted(missing)}")
    sets = {name: {i for pair in pairs for i in pair} for name, pairs in found.items()}
    sets["edges"] = {tuple(sorted(pair)) for pair in found["FACEMESH_TESSELATION"]}
    return sets


#: The canonical mesh and the wheel's ``FACEMESH_TESSELATION`` triangulate the same 468 points
#: differently in places (the tesselation leaves the mouth open, some quads are split the other
#: way): 82 % of the canonical mesh's edges are tesselation edges. Fewer would mean another mesh.
MIN_SHARED_EDGES = 0.75


def mesh_edges(triangles: np.ndarray) -> set[tuple[int, int]]:
    """The undirected edges of a triangle mesh as sorted pairs."""
    pairs = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    return {(int(a), int(b)) for a, b in pairs}


# ------------------------------------------------------------------------------ landmark order


def procrustes_residual(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Per-point distances (target units) after the best similarity transform of source onto target."""
    scale, rotation, translation = similarity_transform(source, target)
    return np.linalg.norm(scale * np.asarray(source, np.float64) @ rotation.T + translation - target, axis=1)


def order_check(canonical: np.ndarray, detections: list[np.ndarray]) -> dict[str, float]:
    """Procrustes residuals (median, 90th percentile, % of the inter-ocular distance 33-263) of
    the canonical mesh against detected meshes (x, y, z px; y down, z away from the camera), in
    MediaPipe's order, in the x-mirrored order and in a random order."""
    mirror = cKDTree(canonical).query(canonical * [-1.0, 1.0, 1.0])[1]
    shuffled = np.random.default_rng(0).permutation(N_MESH)
    out: dict[str, list[float]] = {"order": [], "mirrored": [], "random": []}
    for mesh in detections:
        points = mesh.astype(np.float64) * [1.0, -1.0, -1.0]
        iod = float(np.linalg.norm(points[263, :2] - points[33, :2]))
        for name, order in (("order", np.arange(N_MESH)), ("mirrored", mirror), ("random", shuffled)):
            out[name].append(100.0 * procrustes_residual(canonical[order], points) / iod)
    stats = {}
    for name, values in out.items():
        v = np.concatenate(values)
        stats[f"{name}_median"], stats[f"{name}_p90"] = float(np.median(v)), float(np.percentile(v, 90))
    return stats


# ------------------------------------------------------------------------------------- renders


@dataclass
class View:
    """One render: the image, the skin's camera-space vertices (V, 3) mm, its camera and pose."""

    image: np.ndarray
    vertices: np.ndarray
    camera: Camera
    yaw: float
    pitch: float


def brow_mask(model: MorphableModel, points: np.ndarray) -> np.ndarray:
    """(V,) float64 in {0, 1}: the model's brows to paint, the vertices inside MediaPipe's brow
    outlines (upper and lower brow rows, ``facegeo.skin_mask.RIGHT_BROW``/``LEFT_BROW``) placed
    at ``points`` (468, 3) mm on the mean shape, seen from the front, and not behind them."""
    mean = model.mean_shape.astype(np.float64)
    mask = np.zeros(model.n_vertices)
    for outline in (RIGHT_BROW, LEFT_BROW):
        corners = points[outline]
        inside = Polygon(corners[:, :2]).contains_points(mean[:, :2]) & (mean[:, 2] > corners[:, 2].min() - 10.0)
        mask[inside] = 1.0
    return mask


class FaceRenderer:
    """Photo-like renders of random faces of the model with its parts (eyes, mouth interior),
    lips painted on the model's lip region and brows inside MediaPipe's brow outlines placed at
    ``points`` (468, 3) mm on the mean shape (the registration's: a painting of our own would
    move the detected brows wherever it is put)."""

    IRIS_SRGB = ((0.36, 0.24, 0.15), (0.22, 0.14, 0.09), (0.30, 0.42, 0.55), (0.35, 0.38, 0.24))
    LIP_SRGB = (0.62, 0.33, 0.33)
    BROW_SRGB = ((0.20, 0.14, 0.10), (0.35, 0.25, 0.16), (0.10, 0.08, 0.07))

    def __init__(self, model: MorphableModel, points: np.ndarray, size: int = RENDER_SIZE):
        self.model, self.size = model, size
        self.parts: tuple[PartModel, ...] = load_parts(model)
        self.lips = vertex_regions(model)["lips"][:, None]
        self.brows = brow_mask(model, points)[:, None]
        self.anchor = np.asarray(ModelSignature.of(model).anchor, np.float64)
        self._eyeball_textures: dict[tuple[float, ...], np.ndarray] = {}

    def _eyeball_texture(self, part: PartModel, iris: tuple[float, float, float]) -> np.ndarray:
        if iris not in self._eyeball_textures:
            self._eyeball_textures[iris] = srgb_to_linear(eyeball_texture(part, iris)).astype(np.float32)
        return self._eyeball_textures[iris]

    def __call__(self, rng: np.random.Generator) -> View:
        model, size = self.model, self.size
        face = random_face(model, rng, size, max_yaw=MAX_YAW, sigma_id=SIGMA_ID, expressions=EXPRESSIONS)
        yaw, pitch = rng.uniform(-MAX_YAW, MAX_YAW), rng.uniform(-MAX_PITCH, MAX_PITCH)
        rotation = rotation_from_euler(yaw, pitch, rng.uniform(-MAX_ROLL, MAX_ROLL))
        # keep random_face's framing: the landmark centroid stays where its rotation put it
        translation = face["translation"] + face["rotation"].astype(np.float64) @ self.anchor - rotation @ self.anchor
        gamma = torch.from_numpy(face["gamma"])
        with torch.no_grad():
            skin = model.shape(torch.from_numpy(face["alpha"]), torch.from_numpy(face["delta"])).numpy().astype(np.float64)
        parts = part_vertices(self.parts, model, face["alpha"], face["delta"])

        def irradiance(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
            normals = vertex_normals(vertices @ rotation.T, triangles)
            return sh_irradiance(torch.from_numpy(normals).float(), gamma).numpy().astype(np.float64)

        albedo = face["albedo"].astype(np.float64)
        lip = srgb_to_linear(np.asarray(self.LIP_SRGB)) * rng.uniform(0.8, 1.15)
        brow = srgb_to_linear(np.asarray(self.BROW_SRGB[rng.integers(len(self.BROW_SRGB))]))
        albedo = albedo * (1 - self.lips) + np.minimum(albedo * lip / 0.45, 1.0) * self.lips
        albedo = albedo * (1 - 0.85 * self.brows) + brow * 0.85 * self.brows
        vertices, triangles, colours = [skin], [model.triangles], [albedo * irradiance(skin, model.triangles)]
        offset, textured = len(skin), []
        iris = self.IRIS_SRGB[rng.integers(len(self.IRIS_SRGB))]
        for part in self.parts:
            v = parts[part.name].astype(np.float64)
            light = irradiance(v, part.triangles)
            if part.radial_mm is not None:  # eyeballs: textured per pixel below
                textured.append((sum(len(t) for t in triangles), part, self._eyeball_texture(part, iris), light))
                colours.append(light)
            else:
                colours.append(srgb_to_linear(np.asarray(PART_MATERIALS[part.name]["albedo"])) * light)
            vertices.append(v)
            triangles.append(part.triangles + offset)
            offset += len(v)
        all_vertices = np.concatenate(vertices) @ rotation.T + translation
        all_triangles = np.concatenate(triangles)
        all_colours = np.concatenate(colours)
        camera = Camera.for_image(size, size)
        tri, bary, _ = rasterize_mesh(all_vertices, all_triangles, camera)
        covered = tri >= 0
        image = np.zeros((size, size, 3))
        image[covered] = np.einsum("nk,nkc->nc", bary[covered], all_colours[all_triangles[tri[covered]]])
        for first, part, texture, light in textured:
            here = covered & (tri >= first) & (tri < first + len(part.triangles))
            local, weights = tri[here] - first, bary[here].astype(np.float64)
            uv = np.einsum("nk,nkc->nc", weights, part.uv[part.uv_triangles[local]].astype(np.float64))
            albedo_px = sample_uv(texture, uv[None].astype(np.float32))[0]
            image[here] = albedo_px * np.einsum("nk,nkc->nc", weights, light[part.triangles[local]])
        ys, xs = np.mgrid[0:size, 0:size] / size
        c0, c1 = rng.uniform(0, 1, 3), rng.uniform(0, 1, 3)
        ramp = np.cos(rng.uniform(0, np.pi)) * xs + np.sin(rng.uniform(0, np.pi)) * ys
        background = c0 + (c1 - c0) * ((ramp - ramp.min()) / max(np.ptp(ramp), 1e-6))[..., None]
        background = np.clip(background + rng.normal(0, 0.03, background.shape), 0, 1)
        srgb = np.where(covered[..., None], linear_to_srgb(np.clip(image, 0, 1)), background)
        srgb = cv2.GaussianBlur(srgb.astype(np.float32), (0, 0), 0.6)  # a lens, not aliased edges
        return View(image=(np.clip(srgb, 0, 1) * 255).round().astype(np.uint8),
                    vertices=(skin @ rotation.T + translation).astype(np.float32), camera=camera, yaw=yaw, pitch=pitch)


@dataclass
class Observations:
    """Renders with a detected mesh: camera-space skin vertices (R, V, 3) mm, detections (R, 468, 2)
    px (facegeo's convention, pixel centres at +0.5), the detected 3D meshes (R, 468, 3) as the
    detector gives them, cameras, poses (R, 2) yaw/pitch degrees, and the number of renders
    without a detection."""

    vertices: np.ndarray
    detections: np.ndarray
    meshes: np.ndarray
    cameras: list[Camera]
    poses: np.ndarray
    missed: int


def observe(renderer: FaceRenderer, detector: MediaPipeFaceMesh, count: int, seed: int,
            keep: Path | None = None) -> Observations:
    """Render ``count`` faces (seed ``seed``) and detect the mesh in each; renders without a face
    are counted and skipped. ``keep``: also write the first renders there (PNG, for a look)."""
    rng = np.random.default_rng(seed)
    vertices, detections, meshes, cameras, poses, missed = [], [], [], [], [], 0
    for index in range(count):
        view = renderer(rng)
        faces = detector(view.image)
        if keep is not None and index < 4:
            cv2.imwrite(str(keep / f"render_{seed}_{index}.png"), cv2.cvtColor(view.image, cv2.COLOR_RGB2BGR))
        if not faces:
            missed += 1
            continue
        vertices.append(view.vertices)
        detections.append(faces[0].mesh[:, :2] + 0.5)
        meshes.append(faces[0].mesh)
        cameras.append(view.camera)
        poses.append((view.yaw, view.pitch))
    return Observations(np.stack(vertices), np.stack(detections).astype(np.float64), np.stack(meshes),
                        cameras, np.asarray(poses), missed)


# ----------------------------------------------------------------------------------- measuring


def project_points(obs: Observations, corners: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points given by vertex ids ``corners`` (..., 3) and barycentrics ``weights`` (..., 3) in
    every render: (R, ..., 2) pixels and (R, ...) depth (mm along −Z)."""
    cam = np.einsum("r...kc,...k->r...c", obs.vertices[:, corners].astype(np.float64), weights)
    pixels = np.stack([to_pixels(c, camera) for c, camera in zip(cam, obs.cameras)])
    return pixels, -cam[..., 2]


def interocular_px(obs: Observations, model: MorphableModel) -> np.ndarray:
    """(R,) distance between the projected outer eye-corner landmark vertices, px."""
    ids = model.landmark_indices[OUTER_EYE_CORNERS]
    pixels, _ = project_points(obs, ids[:, None].repeat(3, 1), np.full((2, 3), 1 / 3))
    return np.linalg.norm(pixels[:, 0] - pixels[:, 1], axis=-1)


def reprojection(obs: Observations, model: MorphableModel, triangle: np.ndarray,
                 barycentric: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per render and point: error px (R, 468), error % inter-ocular distance (R, 468) and error
    mm at the point's depth (R, 468)."""
    pixels, depth = project_points(obs, model.triangles[triangle], barycentric.astype(np.float64))
    error = np.linalg.norm(pixels - obs.detections, axis=-1)
    focal = np.array([c.focal for c in obs.cameras])[:, None]
    return error, 100.0 * error / interocular_px(obs, model)[:, None], error * depth / focal


def region_of_points(sets: dict[str, set[int]]) -> np.ndarray:
    """(468,) region name of each point (:data:`REGIONS`, else :data:`OTHER_REGION`)."""
    region = np.full(N_MESH, OTHER_REGION, dtype=object)
    for name, members in reversed(REGIONS):
        for s in members:
            region[sorted(sets[s])] = name
    return region


def error_table(errors: dict[str, tuple[np.ndarray, np.ndarray]], region: np.ndarray) -> str:
    """Markdown table: per region and mapping, median and 90th percentile of the error in px and
    % IOD over held-out renders × points."""
    lines = ["| region | points | " + " | ".join(f"{name} median px / % IOD | {name} p90 px / % IOD" for name in errors) + " |",
             "| --- | --- | " + " | ".join("--- | ---" for _ in errors) + " |"]
    for name in ["all", *[r for r, _ in REGIONS], OTHER_REGION]:
        keep = np.ones(N_MESH, bool) if name == "all" else region == name
        cells = []
        for px, iod in errors.values():
            cells.append(f"{np.median(px[:, keep]):.2f} / {np.median(iod[:, keep]):.2f}")
            cells.append(f"{np.percentile(px[:, keep], 90):.2f} / {np.percentile(iod[:, keep], 90):.2f}")
        lines.append(f"| {name} | {int(keep.sum())} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------- refinement


def surface_samples(model: MorphableModel, n: int = SAMPLES_PER_EDGE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points on the face region's triangles, a barycentric grid of ``n`` steps per edge:
    triangle (S,) int64, barycentric (S, 3) float64, mean-shape position (S, 3) mm."""
    face = np.flatnonzero(model.face_mask[model.triangles].all(axis=1))
    grid = np.array([(i, j, n - i - j) for i in range(n + 1) for j in range(n + 1 - i)], np.float64) / n
    triangle = np.repeat(face, len(grid))
    barycentric = np.tile(grid, (len(face), 1))
    position = np.einsum("skc,sk->sc", model.mean_shape[model.triangles[triangle]].astype(np.float64), barycentric)
    return triangle, barycentric, position


def refine(obs: Observations, model: MorphableModel, triangle: np.ndarray,
           barycentric: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The refined (triangle, barycentric) per point (see the module docstring, step 3) and (468,)
    the distance moved on the mean shape, mm (0 where the prior stays). Coarse to fine: the
    candidates are first the surface samples within :data:`SEARCH_RADIUS_MM` on a grid of 1 step
    per edge (the vertices), then those within :data:`FINE_RADIUS_MM` of the best of them on a grid of
    :data:`SAMPLES_PER_EDGE` steps."""
    coarse, fine = surface_samples(model, 1), surface_samples(model, SAMPLES_PER_EDGE)
    coarse_tree, fine_tree = cKDTree(coarse[2]), cKDTree(fine[2])
    mean = model.mean_shape.astype(np.float64)
    prior = np.einsum("pkc,pk->pc", mean[model.triangles[triangle]], barycentric.astype(np.float64))
    iod_mm = float(np.linalg.norm(np.subtract(*mean[model.landmark_indices[OUTER_EYE_CORNERS]])))
    px_to_mm = iod_mm / interocular_px(obs, model)  # (R,)
    new_tri, new_bary, moved = triangle.copy(), barycentric.astype(np.float64).copy(), np.zeros(N_MESH)

    def errors(i: int, c_tri: np.ndarray, c_bary: np.ndarray) -> np.ndarray:
        pixels, _ = project_points(obs, model.triangles[c_tri], c_bary)  # (R, K, 2)
        return np.linalg.norm(pixels - obs.detections[:, i:i + 1], axis=-1) * px_to_mm[:, None]  # (R, K) mm

    for i in range(N_MESH):
        prior_error = errors(i, triangle[i:i + 1], barycentric[i:i + 1].astype(np.float64))[:, 0]
        centre = prior[i]
        for samples, tree, radius in ((coarse, coarse_tree, SEARCH_RADIUS_MM), (fine, fine_tree, FINE_RADIUS_MM)):
            near = np.asarray(tree.query_ball_point(centre, radius), np.int64)
            if near.size == 0:
                continue
            error = errors(i, samples[0][near], samples[1][near])
            distance = np.linalg.norm(samples[2][near] - prior[i], axis=1)
            cost = (np.minimum(error, ROBUST_CAP_MM) ** 2).mean(0) + PRIOR_WEIGHT * distance**2
            best = int(np.argmin(cost))
            centre = samples[2][near[best]]
        prior_cost = (np.minimum(prior_error, ROBUST_CAP_MM) ** 2).mean()
        if cost[best] < prior_cost and (error[:, best] < prior_error).mean() >= CONSISTENCY:
            new_tri[i], new_bary[i], moved[i] = samples[0][near[best]], samples[1][near[best]], distance[best]
    return new_tri, new_bary.astype(np.float32), moved


# ------------------------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent,
                        help="output folder (default: the folder of this script)")
    parser.add_argument("--wheel", type=Path, help=f"use this {WHEEL_NAME} instead of downloading it")
    parser.add_argument("--npm-tarball", type=Path, help=f"use this {NPM_TARBALL} instead of npm pack")
    parser.add_argument("--keep-renders", type=Path, help="write the first renders of each set here")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    timings: dict[str, float] = {}

    def lap(name: str) -> None:
        timings[name] = time.perf_counter() - start - sum(timings.values())

    with tempfile.TemporaryDirectory(prefix="mediapipe-sources-") as tmp:
        wheel = args.wheel or download_wheel(Path(tmp))
        tarball = args.npm_tarball or download_npm_package(Path(tmp))
        for path, expected in ((wheel, WHEEL_SHA256), (tarball, NPM_SHA256)):
            if sha256_of(path) != expected:
                raise SystemExit(f"{path.name}: sha256 {sha256_of(path)}, expected {expected}")
        canonical, canonical_triangles = canonical_face_mesh(tarball)
        sets = connection_sets(wheel)
    lap("sources")
    edges = mesh_edges(canonical_triangles)
    shared = len(edges & sets["edges"]) / len(edges)
    if shared < MIN_SHARED_EDGES:
        raise SystemExit(f"only {shared:.0%} of the canonical mesh's edges are FACEMESH_TESSELATION edges")
    if sets["FACEMESH_FACE_OVAL"] != set(FACE_OVAL):
        raise SystemExit("the wheel's FACEMESH_FACE_OVAL differs from facegeo.skin_mask.FACE_OVAL")
    mirror_gap = float(cKDTree(canonical).query(canonical * [-1.0, 1.0, 1.0])[0].max())
    print(f"canonical mesh: {len(canonical)} vertices, {len(canonical_triangles)} triangles ({shared:.0%} of its "
          f"{len(edges)} edges in the wheel's {len(sets['edges'])}-edge tesselation), mirror symmetric to {mirror_gap:.1e} cm")

    model = load_model()
    detector = MediaPipeFaceMesh(num_threads=1)
    photo = cv2.cvtColor(cv2.imread(str(asset_path("photos/astronaut.png"))), cv2.COLOR_BGR2RGB)
    astronaut = order_check(canonical.astype(np.float64), [detector(photo)[0].mesh])

    registration = register_canonical_mesh(model, canonical, canonical_triangles)
    prior_tri, prior_bary = registration.triangle, registration.barycentric
    lap("registration")

    prior_points = np.einsum("pkc,pk->pc", model.mean_shape[model.triangles[prior_tri]].astype(np.float64), prior_bary)
    renderer = FaceRenderer(model, prior_points)
    fitting = observe(renderer, detector, REFINE_RENDERS, REFINE_SEED, args.keep_renders)
    held_out = observe(renderer, detector, HELD_OUT_RENDERS, HELD_OUT_SEED, args.keep_renders)
    lap("renders and detection")
    rendered = order_check(canonical.astype(np.float64), list(held_out.meshes))

    triangle, barycentric, moved = refine(fitting, model, prior_tri, prior_bary)
    lap("refinement")

    region = region_of_points(sets)
    errors = {}
    prior_px, prior_iod, prior_mm = reprojection(held_out, model, prior_tri, prior_bary)
    refined_px, refined_iod, refined_mm = reprojection(held_out, model, triangle, barycentric)
    errors["NICP only"] = (prior_px, prior_iod)
    errors["refined"] = (refined_px, refined_iod)
    transfer = np.maximum(np.sqrt((refined_mm**2).mean(0)), ERROR_FLOOR_MM).astype(np.float32)
    prior_error = np.maximum(np.sqrt((prior_mm**2).mean(0)), ERROR_FLOOR_MM).astype(np.float32)
    fit_prior_px, _, _ = reprojection(fitting, model, prior_tri, prior_bary)
    fit_refined_px, _, _ = reprojection(fitting, model, triangle, barycentric)

    contour = np.zeros(N_MESH, bool)
    contour[sorted(sets["FACEMESH_FACE_OVAL"])] = True
    arrays = {
        "format_version": np.array(DENSE_FORMAT_VERSION),
        "mediapipe_index": np.arange(N_MESH, dtype=np.int32),
        "triangle": triangle.astype(np.int32),
        "barycentric": barycentric.astype(np.float32),
        "transfer_error_mm": transfer,
        "contour": contour,
        "prior_triangle": prior_tri.astype(np.int32),
        "prior_barycentric": prior_bary.astype(np.float32),
        "prior_error_mm": prior_error,
        "model_triangles_sha256": np.array(triangles_sha256(model.triangles)),
        "n_vertices": np.array(model.n_vertices, np.int64),
        "canonical_vertices": canonical.astype(np.float32),
        "canonical_triangles": canonical_triangles.astype(np.int16),
    }
    name = Path(DENSE_ASSET).name
    with StagedOutput(args.out) as stage:
        with open(stage.path(name), "wb") as handle:
            np.savez_compressed(handle, **arrays)
    lap("writing")

    summary = {
        "renders": {"refine": len(fitting.vertices), "held_out": len(held_out.vertices),
                    "missed": fitting.missed + held_out.missed},
        "astronaut_order_check_pct_iod": astronaut,
        "render_order_check_pct_iod": rendered,
        "moved_points": int((moved > 0).sum()),
        "moved_mm_median_p90_max": [float(np.median(moved[moved > 0])) if (moved > 0).any() else 0.0,
                                    float(np.percentile(moved, 90)), float(moved.max())],
        "refining_renders_median_px": {"NICP only": float(np.median(fit_prior_px)), "refined": float(np.median(fit_refined_px))},
        "transfer_error_mm_median_p90_max": [float(np.median(transfer)), float(np.percentile(transfer, 90)), float(transfer.max())],
        "prior_error_mm_median_p90_max": [float(np.median(prior_error)), float(np.percentile(prior_error, 90)), float(prior_error.max())],
        "nicp_moved_mm_median_p90_max": np.percentile(np.linalg.norm(registration.registered - registration.rigid, axis=1),
                                                      [50, 90, 100]).round(2).tolist(),
        "registered_to_surface_mm_max": float(np.linalg.norm(
            np.einsum("pkc,pk->pc", model.mean_shape[model.triangles[prior_tri]].astype(np.float64), prior_bary)
            - registration.registered, axis=1).max()),
        "seconds": {k: round(v, 1) for k, v in timings.items()},
        "bytes": (args.out / name).stat().st_size,
    }
    print(json.dumps(summary, indent=1))
    print("\nheld-out reprojection error (renders x points):\n" + error_table(errors, region))
    per_region = ["| region | transfer error mm median / p90 | prior error mm median / p90 |", "| --- | --- | --- |"]
    for name_ in [r for r, _ in REGIONS] + [OTHER_REGION]:
        keep = region == name_
        per_region.append(f"| {name_} | {np.median(transfer[keep]):.1f} / {np.percentile(transfer[keep], 90):.1f} | "
                          f"{np.median(prior_error[keep]):.1f} / {np.percentile(prior_error[keep], 90):.1f} |")
    print("\n" + "\n".join(per_region))
    print(f"\n{args.out / name}: {summary['bytes']} bytes, {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
