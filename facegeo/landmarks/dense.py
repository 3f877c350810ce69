"""MediaPipe's 468 face-mesh points as points on the morphable model's surface.

Each MediaPipe point ``i`` (the landmark order of :class:`~facegeo.landmarks.mediapipe_mesh.
MediaPipeFaceMesh`) is a point of one model triangle, ``triangle[i]``, at barycentric coordinates
``barycentric[i]``; it moves with the mesh, so for any vertices of the model (any α, δ, pose) the
468 model points are :func:`points_on_mesh` (torch twin :func:`points_on_mesh_torch`), to be
projected and compared with the detected 468 points.

Two sources, :func:`load_dense_correspondence` picks:

* **bundled** (``assets/mediapipe/ict_dense_correspondence.npz``, made by
  ``assets/mediapipe/make_ict_dense_correspondence.py``; provenance, method and measured errors in
  ``assets/mediapipe/README.md``): for the bundled ICT-FaceKit model only, recognised by the
  sha256 of its triangle array and its vertex count. MediaPipe's canonical face mesh registered
  onto ICT's mean face (rigid + scale from the iBUG-68 pairs, then non-rigid ICP), then refined
  against MediaPipe's own detections on renders of ICT faces.
* **registered** (any other model, e.g. a Hifi3D++ file): the same registration as the bundled
  file's first stage (:func:`register_canonical_mesh`), run against that model's mean shape with
  the canonical mesh stored in the bundled file (about a second); not refined against the
  detector, so its ``transfer_error_mm`` is the bundled file's measured error of that stage.

Per point, ``transfer_error_mm`` says how far (mm, on the surface) the model point may be from
where MediaPipe's detector puts that point on a face: a weight for the fitter
(σ = transfer error), and ``contour`` marks MediaPipe's face-oval points (``FACEMESH_FACE_OVAL``),
silhouette points on turned faces that a fitter should let slide along the contour.

Units: mm, model space (+Y up, +Z out of the face), as :mod:`facegeo.morphable_model`.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from facegeo.errors import InputError, ModelFileError
from facegeo.landmarks.mediapipe_mesh import MEDIAPIPE_TO_IBUG68, N_MESH
from facegeo.landmarks.scheme import CHIN, INNER_FACE
from facegeo.similarity_transform import similarity_transform

if TYPE_CHECKING:
    import torch

    from facegeo.morphable_model import MorphableModel

__all__ = [
    "DENSE_ASSET",
    "DenseCorrespondence",
    "load_dense_correspondence",
    "face_mesh_mirror",
    "read_dense_correspondence",
    "register_canonical_mesh",
    "Registration",
    "triangles_sha256",
    "points_on_mesh",
    "points_on_mesh_torch",
    "REGISTRATION_IBUG",
    "NICP_STEPS",
]

#: The bundled correspondence, relative to ``facegeo.assets``.
DENSE_ASSET = "mediapipe/ict_dense_correspondence.npz"
#: The npz layout this module reads.
DENSE_FORMAT_VERSION = 1

#: The iBUG-68 points whose MediaPipe vertex (``MEDIAPIPE_TO_IBUG68``) and model vertex
#: (``model.landmark_indices``) pin the registration: the inner face (brows, nose, eyes, lips) and
#: the chin. The other 16 jaw points are left out: both schemes put them on a frontal outline,
#: but not on the same surface points (ICT's lie 8-25 mm from MediaPipe's after the rigid fit).
REGISTRATION_IBUG = np.concatenate([[CHIN], INNER_FACE]).astype(np.int64)
REGISTRATION_IBUG.setflags(write=False)

#: ``trimesh.registration.nricp_amberg`` steps (stiffness, landmark weight, normal weight,
#: iterations); the stiffness falls and the landmarks loosen as the fit proceeds (trimesh
#: normalises both meshes by the source's scale, so these do not depend on mm).
NICP_STEPS = ((0.02, 10.0, 0.5, 10), (0.01, 5.0, 0.5, 10), (0.005, 2.5, 0.5, 10), (0.002, 1.0, 0.0, 10))
#: Points farther from the target than this (in trimesh's normalised units, ~0.1 x the canonical
#: mesh's size) get no data term in an NICP iteration.
NICP_DISTANCE_THRESHOLD = 0.1


@dataclass(frozen=True, eq=False)
class DenseCorrespondence:
    """MediaPipe's 468 points on a model's surface.

    Attributes:
        triangle: (468,) int64 index into ``model.triangles``.
        barycentric: (468, 3) float32, rows ≥ 0 summing to 1, weights of the triangle's corners.
        vertex_ids: (468, 3) int64 ``model.triangles[triangle]``.
        transfer_error_mm: (468,) float32 > 0: how far (mm, on the surface) each model point may
            be from where MediaPipe's detector puts it on a face (a per-point σ).
        contour: (468,) bool, MediaPipe's face-oval points (sliding contour points).
        source: ``"bundled"`` (the detector-refined file of the bundled model) or
            ``"registered"`` (registered against this model's mean shape, not refined).
    """

    triangle: np.ndarray
    barycentric: np.ndarray
    vertex_ids: np.ndarray
    transfer_error_mm: np.ndarray
    contour: np.ndarray
    source: str


def triangles_sha256(triangles: np.ndarray) -> str:
    """sha256 (hex) of a (F, 3) triangle array as little-endian int64 bytes in C order: what the
    bundled file records to recognise the model it was made for."""
    return hashlib.sha256(np.ascontiguousarray(triangles, dtype="<i8").tobytes()).hexdigest()


def points_on_mesh(vertices: np.ndarray, corr: DenseCorrespondence) -> np.ndarray:
    """The 468 model points of ``vertices``.

    Args:
        vertices: (V, 3) or (B, V, 3) vertex positions of the model (any units; mm in facegeo).
        corr: the correspondence for this model.
    Returns:
        (468, 3) or (B, 468, 3) points, float32 (float64 for float64 input), same units.
    """
    v = np.asarray(vertices)
    if v.ndim not in (2, 3) or v.shape[-1] != 3 or v.shape[-2] <= int(corr.vertex_ids.max()):
        raise InputError("<array>", "vertices", f"(V, 3) or (B, V, 3) with V > {int(corr.vertex_ids.max())}",
                         f"shape {v.shape}")
    dtype = np.float64 if v.dtype == np.float64 else np.float32
    corners = v[..., corr.vertex_ids, :].astype(dtype)  # (..., 468, 3, 3)
    return np.einsum("...pkc,pk->...pc", corners, corr.barycentric.astype(dtype))


def points_on_mesh_torch(vertices: torch.Tensor, corr: DenseCorrespondence) -> torch.Tensor:
    """The torch twin of :func:`points_on_mesh`: (..., V, 3) -> (..., 468, 3), differentiable,
    in the vertices' dtype and device."""
    import torch

    ids = torch.tensor(corr.vertex_ids, device=vertices.device)  # a copy: the arrays are read-only
    weights = torch.tensor(corr.barycentric, dtype=vertices.dtype, device=vertices.device)
    return (vertices[..., ids, :] * weights[..., None]).sum(-2)


# ------------------------------------------------------------------------------------ loading


def read_dense_correspondence(path: str | Path, model: MorphableModel) -> DenseCorrespondence:
    """Read a correspondence file made for ``model``.

    Raises:
        ModelFileError: the file is unreadable, lacks a key, has wrong shapes or values, or was
            made for another model (its ``model_triangles_sha256`` / ``n_vertices`` differ from
            ``model``'s: the error names both).
    """
    data = _read_npz(Path(path))
    mismatch = _model_mismatch(data, model)
    if mismatch is not None:
        raise ModelFileError(path, *mismatch)
    return _correspondence(path, data, model, "bundled")


_LOADED: dict[tuple[int, bool], tuple[MorphableModel, DenseCorrespondence | None]] = {}


def load_dense_correspondence(model: MorphableModel, *, register: bool = True) -> DenseCorrespondence | None:
    """The 468-point correspondence for ``model``, or None (made once per model object in a
    process: a registration takes seconds and the fitter asks for every photo).

    The bundled file when ``model`` is the model it was made for (same triangle array sha256 and
    vertex count). Any other model: with ``register``, :func:`register_canonical_mesh` against its
    mean shape (about a second; ``source="registered"``, ``transfer_error_mm`` = the bundled
    file's error of that stage); without ``register``, None. None as well when the bundled file
    is missing or the registration fails (fewer than 3 landmark pairs, a non-finite result): the
    caller falls back to the 88 landmarks. Never raises for a model that does not match.
    """
    key = (id(model), register)
    cached = _LOADED.get(key)
    if cached is None or cached[0] is not model:
        cached = (model, _load(model, register))
        _LOADED[key] = cached
    return cached[1]


def face_mesh_mirror() -> np.ndarray:
    """(468,) int64: MediaPipe's left-right permutation (point i of a face is point
    ``mirror[i]`` of its mirror image), from the bundled canonical face mesh, which is
    symmetric about x = 0: each vertex's mirror image is matched to its nearest vertex."""
    global _MIRROR
    if _MIRROR is None:
        from facegeo.assets import asset_path

        canonical = _read_npz(asset_path(DENSE_ASSET))["canonical_vertices"].astype(np.float64)
        # 468² distances (no tree needed, nor scipy's import), from per-axis squares: the bits of
        # summing the (468, 468, 3) squared differences, 32 rows at a time (small temporaries that
        # are reused: a fresh process pays 2 ms instead of 7 ms, most of it page faults)
        mirrored = canonical * np.array([-1.0, 1.0, 1.0])
        x, y, z = canonical.T
        mirror = np.empty(len(canonical), dtype=np.int64)
        for i in range(0, len(canonical), 32):
            rows = mirrored[i:i + 32]
            dx, dy, dz = rows[:, :1] - x, rows[:, 1:2] - y, rows[:, 2:] - z
            mirror[i:i + 32] = np.argmin((dx * dx + dy * dy) + dz * dz, axis=1)
        if not np.array_equal(mirror[mirror], np.arange(len(mirror))):
            raise ModelFileError(DENSE_ASSET, "canonical_vertices", "a face mesh symmetric about x = 0", "no left-right pairing")
        _MIRROR = mirror.astype(np.int64)
        _MIRROR.setflags(write=False)
    return _MIRROR


_MIRROR: np.ndarray | None = None


def _load(model: MorphableModel, register: bool) -> DenseCorrespondence | None:
    from facegeo.assets import asset_path

    try:
        path = asset_path(DENSE_ASSET)
    except FileNotFoundError:
        return None
    data = _read_npz(path)
    if _model_mismatch(data, model) is None:
        return _correspondence(path, data, model, "bundled")
    if not register:
        return None
    try:
        found = register_canonical_mesh(model, data["canonical_vertices"], data["canonical_triangles"])
    except InputError:
        return None
    fields = dict(data, triangle=found.triangle, barycentric=found.barycentric, transfer_error_mm=data["prior_error_mm"])
    return _correspondence(path, fields, model, "registered")


_KEYS = {
    "format_version": (), "triangle": (N_MESH,), "barycentric": (N_MESH, 3), "transfer_error_mm": (N_MESH,),
    "prior_error_mm": (N_MESH,), "contour": (N_MESH,), "mediapipe_index": (N_MESH,), "model_triangles_sha256": (),
    "n_vertices": (), "canonical_vertices": (N_MESH, 3), "canonical_triangles": (None, 3),
}


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as archive:
            data = {k: archive[k] for k in archive.files}
    except Exception as exc:  # noqa: BLE001 - any unreadable file is one error
        raise ModelFileError(path, "file", "a readable dense-correspondence .npz", f"{type(exc).__name__}: {exc}") from None
    for key, shape in _KEYS.items():
        if key not in data:
            raise ModelFileError(path, key, "this key in a dense-correspondence .npz", "missing")
        found = data[key].shape
        if len(found) != len(shape) or any(s is not None and s != f for s, f in zip(shape, found)):
            raise ModelFileError(path, key, f"shape {shape}", str(found))
    if int(data["format_version"]) != DENSE_FORMAT_VERSION:
        raise ModelFileError(path, "format_version", str(DENSE_FORMAT_VERSION), str(data["format_version"]))
    return data


def _model_mismatch(data: dict[str, np.ndarray], model: MorphableModel) -> tuple[str, str, str] | None:
    """(field, expected, found) when the file was made for another model, else None."""
    if int(data["n_vertices"]) != model.n_vertices:
        return "n_vertices", f"the model's {model.n_vertices} vertices", str(int(data["n_vertices"]))
    digest = triangles_sha256(model.triangles)
    if str(data["model_triangles_sha256"]) != digest:
        return "model_triangles_sha256", f"the model's triangles ({digest[:12]}...)", f"{str(data['model_triangles_sha256'])[:12]}..."
    return None


def _correspondence(path: str | Path, data: dict[str, np.ndarray], model: MorphableModel, source: str) -> DenseCorrespondence:
    triangle = np.asarray(data["triangle"], dtype=np.int64)
    barycentric = np.asarray(data["barycentric"], dtype=np.float32)
    error = np.asarray(data["transfer_error_mm"], dtype=np.float32)
    if triangle.min() < 0 or triangle.max() >= len(model.triangles):
        raise ModelFileError(path, "triangle", f"indices in [0, {len(model.triangles)})", f"[{triangle.min()}, {triangle.max()}]")
    if not (np.isfinite(barycentric).all() and barycentric.min() >= 0 and np.abs(barycentric.sum(1) - 1).max() < 1e-4):
        raise ModelFileError(path, "barycentric", "finite rows >= 0 summing to 1", "other values")
    if not (np.isfinite(error).all() and error.min() > 0):
        raise ModelFileError(path, "transfer_error_mm", "finite values > 0", "other values")
    arrays = dict(triangle=triangle, barycentric=barycentric, vertex_ids=model.triangles[triangle].astype(np.int64),
                  transfer_error_mm=error, contour=np.asarray(data["contour"], dtype=bool))
    for a in arrays.values():
        a.setflags(write=False)
    return DenseCorrespondence(**arrays, source=source)


# ------------------------------------------------------------------------------- registration


class Registration(NamedTuple):
    """What :func:`register_canonical_mesh` finds: ``triangle`` (468,) int64 into
    ``model.triangles`` and ``barycentric`` (468, 3) float32 of each point's closest point on the
    face region; ``registered`` (468, 3) float64 mm, the canonical mesh after the non-rigid ICP
    (before that projection); ``rigid`` (468, 3) float64 mm, after the rigid + scale stage."""

    triangle: np.ndarray
    barycentric: np.ndarray
    registered: np.ndarray
    rigid: np.ndarray


def register_canonical_mesh(model: MorphableModel, canonical_vertices: np.ndarray,
                            canonical_triangles: np.ndarray) -> Registration:
    """MediaPipe's canonical face mesh registered onto ``model``'s mean face.

    1. Rigid + scale (Umeyama) from the :data:`REGISTRATION_IBUG` pairs: MediaPipe vertex
       ``MEDIAPIPE_TO_IBUG68[k]`` to model vertex ``model.landmark_indices[k]``.
    2. Non-rigid ICP (``trimesh.registration.nricp_amberg``, Amberg et al. 2007, :data:`NICP_STEPS`)
       onto the model's face region (``model.face_mask`` triangles, subdivided twice so that the
       nearest target point is within a fraction of a mm of the surface), the same pairs as
       landmark constraints.
    3. Each registered vertex's closest point on the face region (Open3D's ``RaycastingScene``).

    Args:
        model: the model (mm); its mean shape is the target.
        canonical_vertices: (468, 3) MediaPipe's canonical mesh (any scale; +Y up, +Z out of the
            face, the subject's right at −X, as the model).
        canonical_triangles: (F, 3) its triangles.
    Returns:
        :class:`Registration`.
    Raises:
        InputError: wrong shapes, or a registration that does not converge to finite values.
    """
    import open3d as o3d
    import trimesh

    source = np.asarray(canonical_vertices, dtype=np.float64)
    source_triangles = np.asarray(canonical_triangles, dtype=np.int64)
    if source.shape != (N_MESH, 3) or source_triangles.ndim != 2 or source_triangles.shape[1] != 3:
        raise InputError("<array>", "canonical mesh", f"({N_MESH}, 3) vertices and (F, 3) triangles",
                         f"{source.shape}, {source_triangles.shape}")
    mean = model.mean_shape.astype(np.float64)
    targets = mean[model.landmark_indices[REGISTRATION_IBUG]]
    pinned = MEDIAPIPE_TO_IBUG68[REGISTRATION_IBUG]
    scale, rotation, translation = similarity_transform(source[pinned], targets)
    rigid = scale * source @ rotation.T + translation
    face = np.flatnonzero(model.face_mask[model.triangles].all(axis=1))
    if face.size == 0:
        raise InputError(model.source, "face_mask", "a face region with triangles", "none")
    surface = trimesh.Trimesh(mean, model.triangles[face], process=False)
    dense = surface.subdivide().subdivide()
    registered = trimesh.registration.nricp_amberg(
        trimesh.Trimesh(rigid, source_triangles, process=False), dense, source_landmarks=pinned,
        target_positions=targets, steps=[list(s) for s in NICP_STEPS], distance_threshold=NICP_DISTANCE_THRESHOLD,
        use_faces=False)
    registered = np.asarray(registered, dtype=np.float64)
    if not np.isfinite(registered).all():
        raise InputError(model.source, "registration", "finite registered points", "NaN/inf")
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mean.astype(np.float32)), o3d.core.Tensor(model.triangles[face].astype(np.uint32)))
    closest = scene.compute_closest_points(o3d.core.Tensor(registered.astype(np.float32)))
    triangle = face[closest["primitive_ids"].numpy().astype(np.int64)]
    uv = closest["primitive_uvs"].numpy().astype(np.float64)
    barycentric = np.clip(np.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], axis=1), 0.0, None)
    barycentric /= barycentric.sum(axis=1, keepdims=True)
    return Registration(triangle, barycentric.astype(np.float32), registered, rigid)
