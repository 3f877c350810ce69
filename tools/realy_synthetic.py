"""Synthetic REALY data sets, for tests and benchmarks (REALY's scans are licensed, not bundled).

:func:`make_dataset` writes the official folder layout for a few synthetic subjects:

* the "scan" of subject ``k``: ICT-FaceKit's mean shape deformed by random identity coefficients
  and a smooth bump field, midpoint-subdivided ``subdivisions`` times (so its vertices are not the
  prediction's), expressed in scan units (mm divided by the subject's metrical scale, about 9, and
  shifted), like REALY's scans;
* its four regions (nose, mouth, forehead, cheek) cut from it by frontal position in the frame of
  the outer eye corners; its 85 keypoints from the ICT-FaceKit keypoint file on the deformed
  (unsubdivided) mesh;
* the prediction ``pred/<k>.obj``: ICT-FaceKit with *other* random identity coefficients and a
  little expression, rotated, scaled and translated, in millimetres;
* ``data/metrical_scale.txt`` (100 lines) and the topology pair ``data/ICT-FaceKit.{obj,txt}``
  so that the official code can read the same inputs.

Quirks exercised on purpose: subject 1's prediction is written with quads (``f v/vt`` tokens),
subject 2's nose region has a duplicated vertex (used by one face) and an unreferenced vertex,
subject 3's mouth region has a face that repeats a vertex (a degenerate triangle).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeo.eval.realy_io import barycentric_points, read_keypoint_file
from facegeo.mesh_io import obj_text
from facegeo.landmarks.scheme import IBUG68
from make_ict_keypoints import eye_frame  # tools/, beside this file

__all__ = ["SyntheticRealy", "make_dataset", "dataset_digest", "REGION_BOXES", "ict_keypoint_file"]

#: Regions by frontal position in the eye frame (x from outer eye corner 36 to 45, unit = their
#: distance, y up): (|x| range, y range).
REGION_BOXES = {
    "nose": ((0.0, 0.24), (-0.58, 0.02)),
    "mouth": ((0.0, 0.42), (-1.0, -0.6)),
    "forehead": ((0.0, 0.62), (0.12, 0.8)),
    "cheek": ((0.3, 0.74), (-0.85, -0.12)),
}


@dataclass(frozen=True)
class SyntheticRealy:
    """Where :func:`make_dataset` wrote things."""

    root: Path
    realy_root: Path  # holds data/...
    pred_dir: Path
    subjects: tuple[str, ...]
    metrical_scales: np.ndarray  # (100,)


def ict_keypoint_file() -> Path:
    """The bundled ICT-FaceKit keypoint file."""
    from facegeo.assets import asset_path

    return asset_path("realy/ICT-FaceKit.txt")


def _subdivide(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint subdivision (each triangle into 4); shared edges get one new vertex."""
    n = len(vertices)
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    unique, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.reshape(3, -1).T + n  # (F, 3): midpoints of edges ab, bc, ca
    mids = (vertices[unique[:, 0]] + vertices[unique[:, 1]]) / 2.0
    a, b, c = triangles.T
    ab, bc, ca = inverse.T
    new = np.concatenate([
        np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1), np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1)
    ])
    return np.concatenate([vertices, mids]), new


def _rotation(rng: np.random.Generator, degrees: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = np.deg2rad(degrees)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def _region_mesh(vertices: np.ndarray, triangles: np.ndarray, keep: np.ndarray, parts: int) -> tuple[np.ndarray, np.ndarray]:
    """The triangles inside ``keep``, only the ``parts`` largest connected pieces, re-indexed."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    tri = triangles[keep[triangles].all(axis=1)]
    n = len(vertices)
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]]])
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    sizes = np.bincount(label[tri[:, 0]], minlength=label.max() + 1)
    tri = tri[np.isin(label[tri[:, 0]], np.argsort(sizes)[::-1][:parts])]
    used = np.unique(tri)
    remap = np.full(len(vertices), -1)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[tri]


def make_dataset(root: str | Path, n_subjects: int = 3, seed: int = 0, subdivisions: int = 1,
                 topology: str = "ICT-FaceKit") -> SyntheticRealy:
    """Write ``n_subjects`` synthetic REALY subjects under ``root`` (see the module doc)."""
    from facegeo.model_files import load_model

    root = Path(root)
    model = load_model()
    mean = model.mean_shape.astype(np.float64)
    tris = model.triangles.astype(np.int64)
    kp_file = ict_keypoint_file()
    kp_tri, kp_w = read_keypoint_file(kp_file, len(tris))
    rng = np.random.default_rng(seed)

    data = root / "realy" / "data"
    (data / "REALY_HIFI3D_keypoints").mkdir(parents=True, exist_ok=True)
    (data / "REALY_scan_region").mkdir(parents=True, exist_ok=True)
    pred_dir = root / "pred"
    pred_dir.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(kp_file, data / f"{topology}.txt")
    (data / f"{topology}.obj").write_text(obj_text(mean, tris, digits=6, comment=False))

    scales = np.ones(100)
    subjects = []
    for k in range(1, n_subjects + 1):
        # ---- scan: identity + bumps, in scan units
        alpha = rng.normal(size=30)
        scan = mean + np.tensordot(alpha, model.id_basis[:30].astype(np.float64), axes=1)
        phase = rng.uniform(0, 2 * np.pi, size=3)
        scan = scan + 1.2 * np.stack([
            np.sin(scan[:, 1] / 9.0 + phase[0]) * np.cos(scan[:, 0] / 11.0),
            np.sin(scan[:, 0] / 8.0 + phase[1]),
            np.cos(scan[:, 1] / 7.0 + phase[2]) * np.sin(scan[:, 0] / 13.0 + phase[1]),
        ], axis=1)
        keypoints_mm = barycentric_points(scan, tris, kp_tri, kp_w)
        dense_v, dense_t = scan, tris
        for _ in range(subdivisions):
            dense_v, dense_t = _subdivide(dense_v, dense_t)
        scale = 8.6 + 0.4 * k + 0.1 * rng.uniform()
        scales[k - 1] = scale
        offset = rng.normal(scale=3.0, size=3)
        to_scan = lambda p: p / scale + offset  # noqa: E731
        scan_units = to_scan(dense_v)
        (data / "REALY_HIFI3D_keypoints" / f"{k}.obj").write_text(obj_text(to_scan(keypoints_mm), digits=6, comment=False))

        # ---- regions, by frontal position in the eye frame of the keypoints
        origin, unit, axes = eye_frame(keypoints_mm[IBUG68])
        local = (dense_v - origin) @ axes.T / unit
        front = local[:, 2] > -0.45
        region_dir = data / "REALY_scan_region" / str(k)
        region_dir.mkdir(parents=True, exist_ok=True)
        for name, ((x0, x1), (y0, y1)) in REGION_BOXES.items():
            ax = np.abs(local[:, 0])
            keep = front & (ax >= x0) & (ax <= x1) & (local[:, 1] >= y0) & (local[:, 1] <= y1)
            rv, rt = _region_mesh(scan_units, dense_t, keep, parts=2 if name == "cheek" else 1)
            if k == 2 and name == "nose":  # a duplicated vertex used by one face, and an unused one
                rv = np.concatenate([rv, rv[rt[5, 1]][None], rv[:1] + 0.5])
                rt = rt.copy()
                rt[5, 1] = len(rv) - 2
            if k == 3 and name == "mouth":  # a degenerate face (a repeated vertex)
                rt = np.concatenate([rt, [[rt[0, 0], rt[0, 0], rt[0, 1]]]])
            (region_dir / f"{name}.obj").write_text(obj_text(rv, rt, digits=6, comment=False))

        # ---- prediction: another identity, some expression, rotated, scaled, moved (mm)
        beta = 0.7 * rng.normal(size=30)
        delta = np.zeros(model.exp_basis.shape[0])
        delta[rng.choice(len(delta), 4, replace=False)] = rng.uniform(0.05, 0.25, size=4)
        pred = (mean + np.tensordot(beta, model.id_basis[:30].astype(np.float64), axes=1)
                + np.tensordot(delta, model.exp_basis.astype(np.float64), axes=1))
        rot = _rotation(rng, rng.uniform(8, 20))
        pred = 1.1 * rng.uniform(0.9, 1.1) * pred @ rot.T + rng.normal(scale=20.0, size=3)
        text = obj_text(pred, tris, quads=(k == 1), digits=6, comment=False)
        if k == 1:  # "f v/vt" tokens must be read as their vertex index
            text = "\n".join(
                " ".join([p if i == 0 else f"{p}/{p}" for i, p in enumerate(line.split())]) if line.startswith("f ") else line
                for line in text.splitlines()
            ) + "\n"
        (pred_dir / f"{k}.obj").write_text(text)
        subjects.append(str(k))

    np.savetxt(data / "metrical_scale.txt", scales)
    return SyntheticRealy(root, root / "realy", pred_dir, tuple(subjects), scales)


def dataset_digest(data: SyntheticRealy) -> str:
    """SHA-256 over the written inputs (paths and bytes): tells whether a data set is the same."""
    import hashlib

    h = hashlib.sha256()
    files = sorted(p for p in list(data.realy_root.rglob("*")) + list(data.pred_dir.rglob("*")) if p.is_file())
    for p in files:
        h.update(str(p.relative_to(data.root)).encode())
        h.update(p.read_bytes())
    return h.hexdigest()
