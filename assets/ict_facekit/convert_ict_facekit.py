"""Convert ICT-FaceKit's "Face Model Light" OBJs into facegeo's bundled model file.

Usage (from the repository root, with a checked-out ICT-FaceKit folder)::

    python assets/ict_facekit/convert_ict_facekit.py --ict-root /path/to/ICT-FaceKit \\
        -o assets/ict_facekit/ict_face_model.npz

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
    args = parser.parse_args(argv)
    if not (args.ict_root / "FaceXModel" / "generic_neutral_mesh.obj").is_file():
        parser.error(f"{args.ict_root}: no FaceXModel/generic_neutral_mesh.obj there")
    stats = convert(args.ict_root, args.output, args.uv_layout, args.error_samples)
    json.dump(stats, sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
