"""Convert ICT-FaceKit's "Face Model Light" OBJs into facegeo's bundled model file.

Usage (from the repository root, with a checked-out ICT-FaceKit folder)::

    python assets/ict_facekit/convert_ict_facekit.py --ict-root /path/to/ICT-FaceKit \\
        -o assets/ict_facekit/ict_face_model.npz --parts-output assets/ict_facekit/ict_face_parts.npz

``--parts-output`` also writes the eye and mouth-interior parts (see :func:`convert_parts` and
README.md, "Parts"); it is read by ``facegeo.parts``.

What it reads (all under ``<ict-root>/FaceXModel``):
    generic_neutral_mesh.obj        the mean shape, the polygons and the UVs
    identity000.obj ... identityNNN.obj
                                    PCA identity modes; ICT's own scripts add ``w * (identity_i -
                                    neutral)`` with ``w ~ N(0, 1)``, so ``identity_i - neutral`` is
                                    already one standard deviation: it is stored as is
    <expression>.obj                the 53 ARKit-style blendshapes named in vertex_indices.json
                                    ("expressions"); basis = expression - neutral, the coefficient
                                    is the blendshape weight (1 = the full expression)

What it keeps: the skin of the head, i.e. vertices [0, 11248) = "Face" [0:9408] + "Head and
Neck" [9409:11247] and the polygons [0, 11144) that use only those vertices (ICT README). Mouth
socket, eyes, teeth, gums and eyelashes are dropped.

Conversions (all checked by assertions below, with the measured numbers printed):
    units   ICT is in centimetres (outer eye corners 89 mm apart, pupil-centre proxy 63 mm
            apart after x10); everything is multiplied by 10 to millimetres.
    axes    ICT is already right-handed, +Y up, +Z out of the face, +X towards the subject's
            left: nothing is flipped.
    origin  ICT's own origin (inside the head, roughly between the ears) is kept.
    polygons each quad (a, b, c, d) of the OBJ becomes the two triangles (a, b, c), (a, c, d),
            emitted once, in file order (triangle 2i and 2i+1 come from quad i; a triangle is
            copied as is). ICT's quads are counter-clockwise seen from outside, so the
            triangles are too (checked on the nose tip).
    UVs     face-varying, read from the OBJ's ``vt`` lines and ``f v/vt`` indices, origin bottom
            left as in OBJ. ICT puts the face in UDIM tile 1001 (u in [0, 1]) and the head and
            neck in tile 1002 (u in [1, 2]). facegeo's UVs live in the unit square, so the default
            ``--uv-layout packed`` scales tile 1001 by 0.75 into [0, 0.75] x [0.25, 1] and tile
            1002 by 0.25 into [0.75, 1] x [0.75, 1] (no overlap; the face keeps 56% of the
            texels). ``--uv-layout udim`` keeps ICT's coordinates unchanged (u up to 2).
    albedo  ICT Light has no albedo model: the mean albedo is a uniform linear mid-grey 0.5 and
            the texture basis is empty (0, V, 3); the fit's per-channel SH lighting absorbs the
            skin colour.

Everything here is our own code; only the data comes from ICT-FaceKit (MIT, see LICENSE).
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

FORMAT_VERSION = 1

#: ICT README, "Face Model Topology": vertices [0:11247] are Face + Head and Neck, polygons
#: [0:11143] use only them.
N_KEEP_VERTICES = 11248
N_KEEP_POLYGONS = 11144
#: "Face" region [0:9408] and "Narrow face area" [0:6705] (ICT README, "Face Area Details").
N_FACE_VERTICES = 9409
N_NARROW_FACE_VERTICES = 6706

#: ICT README, "Facial Landmarks": Multi-PIE 68 landmark vertex indices (0-based).
MULTI_PIE_68 = [
    1225,
    1888,
    1052,
    367,
    1719,
    1722,
    2199,
    1447,
    966,
    3661,
    4390,
    3927,
    3924,
    2608,
    3272,
    4088,
    3443,
    268,
    493,
    1914,
    2044,
    1401,
    3615,
    4240,
    4114,
    2734,
    2509,
    978,
    4527,
    4942,
    4857,
    1140,
    2075,
    1147,
    4269,
    3360,
    1507,
    1542,
    1537,
    1528,
    1518,
    1511,
    3742,
    3751,
    3756,
    3721,
    3725,
    3732,
    5708,
    5695,
    2081,
    0,
    4275,
    6200,
    6213,
    6346,
    6461,
    5518,
    5957,
    5841,
    5702,
    5711,
    5533,
    6216,
    6207,
    6470,
    5517,
    5966,
]
#: The 20 lip points of the 88-point set re-use iBUG 48..67.
LIP_FROM_IBUG = list(range(48, 68))

CM_TO_MM = 10.0
UV_PACKING = {  # tile index -> (scale, offset u, offset v) for --uv-layout packed
    0: (0.75, 0.0, 0.25),
    1: (0.25, 0.75, 0.75),
}

_V_LINE = re.compile(rb"^v\s+(\S+)\s+(\S+)\s+(\S+)", re.MULTILINE)


def read_vertices(path: Path) -> np.ndarray:
    """(N, 3) float64 positions of the ``v`` lines of an OBJ file, in file order."""
    data = path.read_bytes()
    values = _V_LINE.findall(data)
    return np.array(values, dtype=np.float64).reshape(-1, 3)


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray, list[list[int]], list[list[int]]]:
    """Positions (N, 3), UVs (T, 2) and the polygons as 0-based vertex and UV index lists."""
    positions, uvs, polygons, polygon_uvs = [], [], [], []
    with path.open("r", encoding="utf-8", errors="replace") as handle:
        for line in handle:
            if line.startswith("v "):
                positions.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("vt "):
                uvs.append([float(x) for x in line.split()[1:3]])
            elif line.startswith("f "):
                corners = [c.split("/") for c in line.split()[1:]]
                if any(len(c) < 2 or not c[1] for c in corners):
                    raise ValueError(f"{path}: polygon without UV indices: {line.strip()}")
                polygons.append([int(c[0]) - 1 for c in corners])
                polygon_uvs.append([int(c[1]) - 1 for c in corners])
    return np.array(positions), np.array(uvs), polygons, polygon_uvs


def triangulate(polygons: list[list[int]]) -> np.ndarray:
    """Quads (a, b, c, d) -> (a, b, c), (a, c, d); triangles copied; file order kept."""
    triangles = []
    for poly in polygons:
        if len(poly) == 3:
            triangles.append(poly)
        elif len(poly) == 4:
            a, b, c, d = poly
            triangles.append([a, b, c])
            triangles.append([a, c, d])
        else:
            raise ValueError(f"polygon with {len(poly)} corners (only triangles and quads expected)")
    return np.array(triangles, dtype=np.int64)


def pack_uvs(uv: np.ndarray, layout: str) -> np.ndarray:
    """Map ICT's two UDIM tiles into the unit square (see the module docstring)."""
    if layout == "udim":
        return uv.copy()
    tile = np.floor(uv[:, 0]).astype(int).clip(0, 1)
    out = np.empty_like(uv)
    for t, (scale, du, dv) in UV_PACKING.items():
        sel = tile == t
        out[sel, 0] = (uv[sel, 0] - t) * scale + du
        out[sel, 1] = uv[sel, 1] * scale + dv
    return out


def git_commit(root: Path) -> str:
    try:
        out = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
        )
        return out.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def measure(mean: np.ndarray, lm: np.ndarray) -> dict[str, float]:
    """Anthropometric sanity numbers (mm) from the 68 landmark vertices."""
    p = mean[lm]
    right_eye = p[36:42].mean(axis=0)
    left_eye = p[42:48].mean(axis=0)
    return {
        "outer_eye_corners_36_45_mm": float(np.linalg.norm(p[36] - p[45])),
        "inner_eye_corners_39_42_mm": float(np.linalg.norm(p[39] - p[42])),
        "eye_centres_mm": float(np.linalg.norm(right_eye - left_eye)),
        "nasion_27_to_chin_8_mm": float(np.linalg.norm(p[27] - p[8])),
        "mouth_width_48_54_mm": float(np.linalg.norm(p[48] - p[54])),
    }


def float16_error(
    id32: np.ndarray, exp32: np.ndarray, id16: np.ndarray, exp16: np.ndarray, n: int, seed: int = 0
) -> tuple[float, float]:
    """Max and RMS (mm) of |S16 - S32| over n random instances alpha, delta ~ N(0, 1), all vertices."""
    rng = np.random.default_rng(seed)
    d_id = (id16.astype(np.float64) - id32).reshape(id32.shape[0], -1)
    d_exp = (exp16.astype(np.float64) - exp32).reshape(exp32.shape[0], -1)
    max_err, sq_sum, count = 0.0, 0.0, 0
    for start in range(0, n, 100):
        m = min(100, n - start)
        alpha = rng.standard_normal((m, d_id.shape[0]))
        delta = rng.standard_normal((m, d_exp.shape[0]))
        err = (alpha @ d_id + delta @ d_exp).reshape(m, -1, 3)
        dist = np.linalg.norm(err, axis=-1)
        max_err = max(max_err, float(dist.max()))
        sq_sum += float(np.sum(dist**2))
        count += dist.size
    return max_err, float(np.sqrt(sq_sum / count))


def convert(ict_root: Path, output: Path, uv_layout: str = "packed", n_error_samples: int = 1000) -> dict:
    model_dir = ict_root / "FaceXModel"
    config = json.loads((model_dir / "vertex_indices.json").read_text())
    expression_names = list(config["expressions"])

    positions, uvs, polygons, polygon_uvs = read_obj(model_dir / "generic_neutral_mesh.obj")
    n_all = positions.shape[0]
    kept_polys = polygons[:N_KEEP_POLYGONS]
    kept_poly_uvs = polygon_uvs[:N_KEEP_POLYGONS]
    assert max(max(p) for p in kept_polys) < N_KEEP_VERTICES, "kept polygons use dropped vertices"
    assert min(min(p) for p in polygons[N_KEEP_POLYGONS:]) >= 0

    triangles = triangulate(kept_polys)
    tri_uv_raw = triangulate(kept_poly_uvs)
    used_uv = np.unique(tri_uv_raw)
    remap = np.full(uvs.shape[0], -1, dtype=np.int64)
    remap[used_uv] = np.arange(used_uv.size)
    uv_triangles = remap[tri_uv_raw]
    uv = pack_uvs(uvs[used_uv], uv_layout).astype(np.float32)
    assert np.unique(triangles).size == N_KEEP_VERTICES, "unused vertices in the kept range"

    mean = positions[:N_KEEP_VERTICES] * CM_TO_MM

    def deltas(names: list[str]) -> np.ndarray:
        out = np.empty((len(names), N_KEEP_VERTICES, 3), dtype=np.float64)
        for k, name in enumerate(names):
            v = read_vertices(model_dir / f"{name}.obj")
            if v.shape[0] != n_all:
                raise ValueError(f"{name}.obj: {v.shape[0]} vertices, neutral has {n_all}")
            out[k] = (v[:N_KEEP_VERTICES] - positions[:N_KEEP_VERTICES]) * CM_TO_MM
        return out

    identity_names = []
    while (model_dir / f"identity{len(identity_names):03d}.obj").is_file():
        identity_names.append(f"identity{len(identity_names):03d}")
    id32 = deltas(identity_names)
    exp32 = deltas(expression_names)

    # ---- checks: units, axes, orientation, landmark geometry
    lm68 = np.array(MULTI_PIE_68, dtype=np.int64)
    sizes = measure(mean, lm68)
    assert 55.0 < sizes["eye_centres_mm"] < 75.0, sizes
    assert 80.0 < sizes["outer_eye_corners_36_45_mm"] < 105.0, sizes
    p = mean[lm68]
    assert p[36:48, 1].mean() > p[48:68, 1].mean(), "+Y should point up (eyes above the mouth)"
    assert p[30, 2] > p[0, 2] and p[30, 2] > p[16, 2], "+Z should point out of the face"
    assert p[36, 0] < 0 < p[45, 0], "+X should point to the subject's left"

    a, b, c = (mean[triangles[:, k]] for k in range(3))
    face_normals = np.cross(b - a, c - a)
    nose_tip = int(np.argmax(mean[:, 2]))
    around_tip = face_normals[np.any(triangles == nose_tip, axis=1)]
    assert np.all(around_tip[:, 2] > 0), "triangles around the nose tip should face +Z"
    signed_volume = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
    assert signed_volume > 0, "triangles should be counter-clockwise seen from outside"

    landmark_indices = np.concatenate([lm68, lm68[np.array(LIP_FROM_IBUG)]])
    face_mask = np.zeros(N_KEEP_VERTICES, dtype=bool)
    face_mask[:N_FACE_VERTICES] = True
    narrow_face_mask = np.zeros(N_KEEP_VERTICES, dtype=bool)
    narrow_face_mask[:N_NARROW_FACE_VERTICES] = True

    id16 = id32.astype(np.float16)
    exp16 = exp32.astype(np.float16)
    assert np.all(np.isfinite(id16)) and np.all(np.isfinite(exp16)), "float16 overflow"
    err_max, err_rms = float16_error(id32, exp32, id16, exp16, n_error_samples)

    commit = git_commit(ict_root)
    arrays = {
        "format_version": np.array(FORMAT_VERSION, dtype=np.int64),
        "name": np.array(
            f"ICT-FaceKit Face Model Light ({len(identity_names)} id, {len(expression_names)} exp)"
        ),
        "source_commit": np.array(commit),
        "mean_shape": mean.astype(np.float32),
        "id_basis": id16,
        "exp_basis": exp16,
        "expression_names": np.array(expression_names),
        "triangles": triangles,
        "uv": uv,
        "uv_triangles": uv_triangles,
        "uv_layout": np.array(uv_layout),
        "landmark_indices": landmark_indices,
        "face_mask": face_mask,
        "narrow_face_mask": narrow_face_mask,
        "mean_albedo": np.full((N_KEEP_VERTICES, 3), 0.5, dtype=np.float32),
        "tex_basis": np.zeros((0, N_KEEP_VERTICES, 3), dtype=np.float32),
        "float16_error_mm": np.array([err_max, err_rms], dtype=np.float64),
    }
    output.parent.mkdir(parents=True, exist_ok=True)
    tmp = output.with_name(output.name + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    tmp.replace(output)

    stats = {
        "output": str(output),
        "bytes": output.stat().st_size,
        "source_commit": commit,
        "vertices": N_KEEP_VERTICES,
        "triangles": int(triangles.shape[0]),
        "uv_coordinates": int(uv.shape[0]),
        "n_id": len(identity_names),
        "n_exp": len(expression_names),
        "bbox_min_mm": mean.min(axis=0).round(2).tolist(),
        "bbox_max_mm": mean.max(axis=0).round(2).tolist(),
        **{k: round(v, 2) for k, v in sizes.items()},
        "max_abs_id_delta_mm": round(float(np.abs(id32).max()), 3),
        "max_abs_exp_delta_mm": round(float(np.abs(exp32).max()), 3),
        "float16_max_error_mm": err_max,
        "float16_rms_error_mm": err_rms,
        "signed_volume_ml": round(signed_volume / 1000.0, 1),
    }
    return stats


# ---------------------------------------------------------------------------------------------
# Parts: eyes and mouth interior (ict_face_parts.npz, read by facegeo.parts)

PARTS_FORMAT_VERSION = 1

#: part name -> ICT polygon ranges [start, stop) (README, "Face Model Topology" and "Eyeball
#: Details") and how its identity deltas are stored. "affine": each connected component (a
#: tooth, an eyeball) moves by one affine map per identity mode (fit exact to the error printed);
#: "dense": per-vertex float16 deltas. Only the sclera sub-mesh of each eyeball is kept (see
#: README.md: the inner "iris" mesh is hidden behind it once the sclera is opaque).
PARTS: dict[str, tuple[list[tuple[int, int]], str]] = {
    "eyeballs": ([(21496, 22296), (23094, 23894)], "affine"),
    "eye_sockets": ([(13226, 14034)], "dense"),
    "mouth_socket": ([(11144, 13226)], "dense"),
    "gums_tongue": ([(14034, 17006)], "dense"),
    "teeth": ([(17006, 21496)], "affine"),
}
#: Expression deltas smaller than this (mm) are dropped (the sparse storage); the error this
#: causes is part of the measured error.
SPARSE_EXPRESSION_MM = 0.01
#: ``radial_mm`` of eyeball vertices behind the centre (never seen; far outside any iris).
EYE_BACK_RADIAL_MM = 99.0


def _components(triangles: np.ndarray, n: int) -> np.ndarray:
    """Connected-component label of each of ``n`` vertices (scipy's graph search)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    graph = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int16)


def _affine_identity(mean: np.ndarray, deltas: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Least-squares (n_id, G, 3, 4) maps M with delta_v ~ M[g(v)] @ [p_v, 1] per identity mode."""
    n_id, G = deltas.shape[0], int(groups.max()) + 1
    out = np.zeros((n_id, G, 3, 4))
    for g in range(G):
        sel = groups == g
        X = np.c_[mean[sel], np.ones(sel.sum())]
        for k in range(n_id):
            out[k, g] = np.linalg.lstsq(X, deltas[k, sel], rcond=None)[0].T
    return out


def _eyeball_radial(mean: np.ndarray, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per vertex the distance (mm) from its eyeball's optical axis on the front half (99 behind),
    with the fitted sphere centres (G, 3) and unit axes (G, 3) (centre -> cornea apex)."""
    radial = np.full(len(mean), EYE_BACK_RADIAL_MM)
    centres, axes = [], []
    for g in range(int(groups.max()) + 1):
        sel = np.flatnonzero(groups == g)
        p = mean[sel]
        A = np.c_[2 * p, np.ones(len(p))]
        x = np.linalg.lstsq(A, (p**2).sum(1), rcond=None)[0]
        centre = x[:3]
        rel = p - centre
        dist = np.linalg.norm(rel, axis=1)
        apex = rel[dist > np.quantile(dist, 0.97)].mean(axis=0)  # the cornea bulges beyond the sphere
        axis = apex / np.linalg.norm(apex)
        along = rel @ axis
        r = np.linalg.norm(rel - np.outer(along, axis), axis=1)
        radial[sel] = np.where(along > 0.0, r, EYE_BACK_RADIAL_MM)
        centres.append(centre)
        axes.append(axis)
    return radial, np.array(centres), np.array(axes)


def convert_parts(ict_root: Path, output: Path, n_error_samples: int = 1000) -> dict:
    """Write the eye and mouth-interior parts of ICT-FaceKit to ``output`` (see README.md, "Parts").

    Per part ``p`` the file holds (V_p own vertices, K_p shared skin vertices, F_p triangles):
    ``p__mean`` (V_p, 3) float32 mm; ``p__skin_index`` (K_p,) int64 skin vertices the part's
    triangles also use (they come after the own vertices: local index V_p + k) and their neutral
    positions ``p__skin_mean`` (K_p, 3) float32 (how a model is recognised as the parts' skin); ``p__triangles``
    (F_p, 3) int32, counter-clockwise seen from outside; ``p__uv`` (T_p, 2) float32 (ICT's UVs with
    the UDIM tile offset removed) and ``p__uv_triangles``; identity as ``p__id_basis`` (n_id, V_p,
    3) float16 mm/σ or, for "affine" parts, ``p__group`` (V_p,) int16 and ``p__id_affine`` (n_id,
    G, 3, 4) float32; expressions as sparse ``p__exp_index`` (N,) int16, ``p__exp_vertex`` (N,)
    int32, ``p__exp_delta`` (N, 3) float16 mm per unit weight; eyeballs also ``radial_mm``.
    """
    model_dir = ict_root / "FaceXModel"
    config = json.loads((model_dir / "vertex_indices.json").read_text())
    expression_names = list(config["expressions"])
    positions, uvs, polygons, polygon_uvs = read_obj(model_dir / "generic_neutral_mesh.obj")
    identity_names = []
    while (model_dir / f"identity{len(identity_names):03d}.obj").is_file():
        identity_names.append(f"identity{len(identity_names):03d}")
    targets = {name: read_vertices(model_dir / f"{name}.obj") for name in identity_names + expression_names}

    arrays: dict[str, np.ndarray] = {
        "format_version": np.array(PARTS_FORMAT_VERSION, dtype=np.int64),
        "source_commit": np.array(git_commit(ict_root)),
        "part_names": np.array(list(PARTS)),
        "skin_vertex_count": np.array(N_KEEP_VERTICES, dtype=np.int64),
        "expression_names": np.array(expression_names),
        "n_id": np.array(len(identity_names), dtype=np.int64),
    }
    stats: dict = {"output": str(output), "parts": {}}
    rng = np.random.default_rng(0)
    alpha = rng.standard_normal((n_error_samples, len(identity_names)))
    delta = rng.uniform(0.0, 1.0, (n_error_samples, len(expression_names)))
    for name, (ranges, mode) in PARTS.items():
        polys = [polygons[i] for a, b in ranges for i in range(a, b)]
        poly_uvs = [polygon_uvs[i] for a, b in ranges for i in range(a, b)]
        used = np.unique(np.concatenate(polys))
        own = used[used >= N_KEEP_VERTICES]
        shared = used[used < N_KEEP_VERTICES]
        local = np.full(positions.shape[0], -1, dtype=np.int64)
        local[own] = np.arange(own.size)
        local[shared] = own.size + np.arange(shared.size)
        triangles = local[triangulate(polys)]
        tri_uv_raw = triangulate(poly_uvs)
        used_uv = np.unique(tri_uv_raw)
        remap = np.full(uvs.shape[0], -1, dtype=np.int64)
        remap[used_uv] = np.arange(used_uv.size)
        uv = uvs[used_uv].copy()
        uv[:, 0] -= np.floor(uv[:, 0].min())  # each part has its own texture space
        assert uv[:, 0].max() <= 1.0 + 1e-6, f"{name}: UVs span more than one UDIM tile"
        mean = positions[own] * CM_TO_MM
        full_mean = np.concatenate([mean, positions[shared] * CM_TO_MM])
        dev = {n: (targets[n][own] - positions[own]) * CM_TO_MM for n in targets}
        id64 = np.stack([dev[n] for n in identity_names])
        exp64 = np.stack([dev[n] for n in expression_names])
        prefix = f"{name}__"
        arrays[prefix + "mean"] = mean.astype(np.float32)
        arrays[prefix + "skin_index"] = shared.astype(np.int64)
        arrays[prefix + "skin_mean"] = (positions[shared] * CM_TO_MM).astype(np.float32)
        arrays[prefix + "triangles"] = triangles.astype(np.int32)
        arrays[prefix + "uv"] = uv.astype(np.float32)
        arrays[prefix + "uv_triangles"] = remap[tri_uv_raw].astype(np.int32)
        if mode == "affine":
            assert shared.size == 0, f"{name}: affine parts must not share skin vertices"
            groups = _components(triangles, own.size)
            maps = _affine_identity(mean, id64, groups).astype(np.float32)
            arrays[prefix + "group"] = groups
            arrays[prefix + "id_affine"] = maps
            X = np.c_[mean, np.ones(len(mean))]
            id_stored = np.einsum("kvij,vj->kvi", maps.astype(np.float64)[:, groups], X)
        else:
            arrays[prefix + "id_basis"] = id64.astype(np.float16)
            id_stored = arrays[prefix + "id_basis"].astype(np.float64)
        size = np.linalg.norm(exp64, axis=-1)
        k_idx, v_idx = np.nonzero(size > SPARSE_EXPRESSION_MM)
        arrays[prefix + "exp_index"] = k_idx.astype(np.int16)
        arrays[prefix + "exp_vertex"] = v_idx.astype(np.int32)
        arrays[prefix + "exp_delta"] = exp64[k_idx, v_idx].astype(np.float16)
        exp_stored = np.zeros_like(exp64)
        exp_stored[k_idx, v_idx] = arrays[prefix + "exp_delta"].astype(np.float64)
        if name == "eyeballs":
            radial, centres, axes = _eyeball_radial(mean, arrays[prefix + "group"])
            arrays[prefix + "radial_mm"] = radial.astype(np.float32)
            stats["eye_centres_mm"] = centres.round(2).tolist()
            stats["eye_axes"] = axes.round(3).tolist()

        # ---- checks: orientation (outwards), error of the stored form
        a, b, c = (full_mean[triangles[:, k]] for k in range(3))
        if shared.size == 0:  # (nearly) closed components: positive signed volume each
            comp = _components(triangles, len(full_mean))[triangles[:, 0]]
            vol = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
            assert all(vol[comp == g].sum() > 0 for g in np.unique(comp)), f"{name}: inward triangles"
        else:  # linings of the eye and mouth cavities: oriented consistently with the skin they
            # continue, i.e. every edge shared with a skin triangle runs the other way round
            skin_edges = {tuple(e) for t in triangulate(polygons[:N_KEEP_POLYGONS]) for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
            glob = np.concatenate([own, shared])[triangles]
            edges = [tuple(e) for t in glob.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))]
            same = sum(e in skin_edges for e in edges)
            opposite = sum(e[::-1] in skin_edges for e in edges)
            assert same == 0 and opposite > 0, f"{name}: {same} edges run like the skin's, {opposite} opposite"
        d_true = np.einsum("sk,kvc->svc", alpha, id64) + np.einsum("sk,kvc->svc", delta, exp64)
        d_stored = np.einsum("sk,kvc->svc", alpha, id_stored) + np.einsum("sk,kvc->svc", delta, exp_stored)
        err = np.linalg.norm(d_stored - d_true, axis=-1)
        stats["parts"][name] = {
            "own_vertices": int(own.size),
            "shared_skin_vertices": int(shared.size),
            "triangles": int(len(triangles)),
            "identity": mode,
            "groups": int(arrays[prefix + "group"].max()) + 1 if mode == "affine" else None,
            "expression_entries": int(k_idx.size),
            "moving_expressions": sorted({expression_names[k] for k in np.unique(k_idx)
                                          if size[k].max() > 1.0}),
            "max_error_mm": round(float(err.max()), 4),
            "rms_error_mm": round(float(np.sqrt((err**2).mean())), 5),
            "max_abs_id_delta_mm": round(float(np.abs(id64).max()), 2),
        }
    output.parent.mkdir(parents=True, exist_ok=True)
    tmp = output.with_name(output.name + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    tmp.replace(output)
    stats["bytes"] = output.stat().st_size
    return stats


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--ict-root", type=Path, required=True, help="checked-out ICT-FaceKit folder")
    parser.add_argument(
        "-o",
        "--output",
        type=Path,
        default=Path(__file__).with_name("ict_face_model.npz"),
        help="output .npz (default: ict_face_model.npz beside this script)",
    )
    parser.add_argument("--uv-layout", choices=["packed", "udim"], default="packed")
    parser.add_argument("--error-samples", type=int, default=1000, help="instances for the float16 error")
    parser.add_argument("--parts-output", type=Path, default=None,
                        help="also write the eye and mouth-interior parts here (e.g. ict_face_parts.npz)")
    parser.add_argument("--parts-only", action="store_true", help="write only --parts-output")
    args = parser.parse_args(argv)
    if not (args.ict_root / "FaceXModel" / "generic_neutral_mesh.obj").is_file():
        parser.error(f"{args.ict_root}: no FaceXModel/generic_neutral_mesh.obj there")
    stats = {} if args.parts_only else convert(args.ict_root, args.output, args.uv_layout, args.error_samples)
    if args.parts_output is not None:
        stats["parts"] = convert_parts(args.ict_root, args.parts_output, args.error_samples)
    json.dump(stats, sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
