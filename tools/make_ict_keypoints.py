"""Make REALY's 85 barycentric keypoints for facegeo's default ICT-FaceKit topology.

REALY (ECCV 2022) aligns a predicted mesh to a scan with 85 keypoints given per topology as a
JSON list of ``[triangle, w0, w1]`` rows: the point is ``w0*a + w1*b + (1-w0-w1)*c`` for the
corners ``(a, b, c)`` of that triangle (0-based, in the OBJ's face order with quads split into
``(a, b, c), (a, c, d)``). The 85 points are the 68 iBUG/Multi-PIE points as seen on a frontal
face (the jaw 0..16 on the frontal outline) followed by 17 extra points on the cheeks and chin.

How this script places them on ICT-FaceKit's generic neutral mesh (``load_model().mean_shape``):

* 0..67: ICT-FaceKit's own 68 Multi-PIE landmark vertices (``landmark_indices[IBUG68]``, from ICT's
  README), each written as weight 1 on one corner of the first triangle that uses the vertex.
* 68..84: where a ray along the face's -Z axis first meets the surface, through a point given in
  the *eye frame*: origin half-way between the outer eye corners (36, 45), unit length their
  distance, +x from 36 to 45, +y the part of (27 - 8) (chin to nasion) orthogonal to x, +z
  towards the viewer. The frontal positions in the table :data:`EXTRA_POINTS` were measured by
  us on the official REALY topology files (HIFI3D, BFM09, FLAME; their 17 extra points are
  exactly such frontal surface points, to 0.01 of the eye-corner distance), averaged over the
  three, symmetrised and rounded to 0.01.

Only some of the 85 points enter the REALY protocol (alignment: 36, 39, 42, 45, 33, 48, 54;
region fits and the error step: 7-9, 17-64, 70, 71, 76, 77); the other jaw and extra points are
written for completeness. ICT's jaw points lie on the visible jaw of a frontal face like REALY's;
its chin points 7-9 sit within the spread of the official templates.

Usage (about 1 s)::

    python tools/make_ict_keypoints.py          # writes assets/realy/ICT-FaceKit.txt
    python tools/make_ict_keypoints.py --obj /tmp/ICT-FaceKit.obj   # also the template OBJ

The OBJ written with ``--obj`` (mean shape in mm, triangles in facegeo's order) together with the
``.txt`` is what the official REALY code needs as ``data/ICT-FaceKit.{obj,txt}``.

``--measure REALY_DATA`` measures the table anew from one's own REALY download (its
``data/{HIFI3D,BFM09,FLAME}.{obj,txt}``: the eye-frame position of each extra point, averaged
over the three, symmetrised, rounded to 0.01) and prints it beside :data:`EXTRA_POINTS`::

    python tools/make_ict_keypoints.py --measure /path/to/REALY/data
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from facegeo.landmarks.scheme import IBUG68, OUTER_EYE_CORNERS

#: Where the keypoint file lives in the source tree (assets/realy/, installed as facegeo.assets).
DEFAULT_OUT = Path(__file__).resolve().parent.parent / "assets" / "realy" / "ICT-FaceKit.txt"

#: The 17 extra REALY points: (index, name, x, y) in the eye frame described above; x < 0 is the
#: subject's right (the side of landmark 36).
EXTRA_POINTS: tuple[tuple[int, str, float, float], ...] = (
    (68, "right infraorbital cheek", -0.46, -0.17),
    (69, "left infraorbital cheek", 0.46, -0.17),
    (70, "right cheek beside the nose wing", -0.29, -0.36),
    (71, "left cheek beside the nose wing", 0.29, -0.36),
    (72, "right cheek beside the mouth corner", -0.48, -0.68),
    (73, "left cheek beside the mouth corner", 0.48, -0.68),
    (74, "right cheekbone", -0.73, -0.16),
    (75, "left cheekbone", 0.73, -0.16),
    (76, "right mid-cheek", -0.61, -0.42),
    (77, "left mid-cheek", 0.61, -0.42),
    (78, "right chin", -0.21, -1.01),
    (79, "chin centre", 0.0, -0.97),
    (80, "left chin", 0.21, -1.01),
    (81, "right lateral cheek", -0.78, -0.38),
    (82, "left lateral cheek", 0.78, -0.38),
    (83, "right lower lateral cheek", -0.71, -0.67),
    (84, "left lower lateral cheek", 0.71, -0.67),
)


def eye_frame(landmarks68: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """(origin, unit length, 3x3 rows = x, y, z axes) of the eye frame of 68 landmark points."""
    p = np.asarray(landmarks68, dtype=np.float64)
    right, left = p[OUTER_EYE_CORNERS]
    origin = (right + left) / 2.0
    ex = left - right
    unit = float(np.linalg.norm(ex))
    ex = ex / unit
    up = p[27] - p[8]
    up = up - ex * float(up @ ex)
    ey = up / np.linalg.norm(up)
    ez = np.cross(ex, ey)
    return origin, unit, np.stack([ex, ey, ez])


def first_hits(vertices: np.ndarray, triangles: np.ndarray, origins: np.ndarray,
               direction: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest ray/triangle hit (float64 Moller-Trumbore over all triangles) for each origin.

    Returns (triangle index, u, v) with hit = (1-u-v)*a + u*b + v*c; raises if a ray misses.
    """
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    e1, e2 = b - a, c - a
    tri_out, u_out, v_out = [], [], []
    for o in origins:
        p = np.cross(direction, e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = o - a
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        v = (q @ direction) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        if not np.any(hit):
            raise RuntimeError(f"ray from {o} misses the mesh")
        idx = np.nonzero(hit)[0]
        best = idx[np.argmin(t[idx])]
        tri_out.append(int(best))
        u_out.append(float(u[best]))
        v_out.append(float(v[best]))
    return np.array(tri_out), np.array(u_out), np.array(v_out)


def ict_keypoints(vertices: np.ndarray, triangles: np.ndarray, landmark68: np.ndarray) -> list[list]:
    """The 85 rows ``[triangle, w0, w1]`` for a mesh and its 68 landmark vertex indices."""
    vertices = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64)
    rows: list[list] = []
    for vertex in landmark68:
        tri, corner = np.argwhere(triangles == int(vertex))[0]
        w = [0, 0]
        if corner < 2:
            w[corner] = 1
        rows.append([int(tri), *w])
    origin, unit, axes = eye_frame(vertices[landmark68])
    xy = np.array([[x, y] for _, _, x, y in EXTRA_POINTS])
    # ray origins well in front of the face (z = 2 eye-corner distances), back in model space
    local = np.column_stack([xy, np.full(len(xy), 2.0)])
    origins = origin + (local * unit) @ axes
    tri, u, v = first_hits(vertices, triangles, origins, -axes[2])
    for t, uu, vv in zip(tri, u, v):
        rows.append([int(t), round(1.0 - uu - vv, 12), round(uu, 12)])
    assert len(rows) == 85
    return rows


#: Symmetric pairs (subject's right, left) among the extra points, and the centre point.
_PAIRS = ((68, 69), (70, 71), (72, 73), (74, 75), (76, 77), (78, 80), (81, 82), (83, 84))
_CENTRE = 79
#: The official topologies the table was measured on (REALY's data/<NAME>.{obj,txt}).
MEASURED_ON = ("HIFI3D", "BFM09", "FLAME")


def extra_point_positions(vertices: np.ndarray, triangles: np.ndarray, rows: list) -> np.ndarray:
    """(17, 2) eye-frame (x, y) of keypoints 68..84 of a topology given by its 85 barycentric rows."""
    from facegeo.eval.realy_io import barycentric_points

    rows_array = np.asarray(rows, dtype=np.float64)
    tri = rows_array[:, 0].astype(np.int64)
    weights = np.column_stack([rows_array[:, 1], rows_array[:, 2], 1.0 - rows_array[:, 1] - rows_array[:, 2]])
    points = barycentric_points(np.asarray(vertices, dtype=np.float64), np.asarray(triangles), tri, weights)
    origin, unit, axes = eye_frame(points[IBUG68])
    return ((points[68:] - origin) @ axes.T / unit)[:, :2]


def averaged_table(positions: list[np.ndarray]) -> dict[int, tuple[float, float]]:
    """{index: (x, y)} of the 17 extra points averaged over topologies, symmetrised, rounded to 0.01."""
    mean = np.mean(positions, axis=0)  # (17, 2)
    table = {}
    for right, left in _PAIRS:
        x = round((abs(mean[right - 68, 0]) + abs(mean[left - 68, 0])) / 2, 2)
        y = round((mean[right - 68, 1] + mean[left - 68, 1]) / 2, 2)
        table[right], table[left] = (-x, y), (x, y)
    table[_CENTRE] = (0.0, round(float(mean[_CENTRE - 68, 1]), 2))
    return table


def measure(data_dir: Path, names: tuple[str, ...] = MEASURED_ON) -> dict[int, tuple[float, float]]:
    """The table :data:`EXTRA_POINTS` measured anew on REALY's official topology files in ``data_dir``."""
    from facegeo.eval.realy_io import read_keypoint_file, read_obj

    positions = []
    for name in names:
        mesh = read_obj(data_dir / f"{name}.obj", f"{name} template")
        read_keypoint_file(data_dir / f"{name}.txt", len(mesh.triangles))  # checks the file
        rows = json.loads((data_dir / f"{name}.txt").read_text())
        positions.append(extra_point_positions(mesh.vertices, mesh.triangles, rows))
    return averaged_table(positions)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("-o", "--output", type=Path, default=DEFAULT_OUT, help="keypoint file to write")
    parser.add_argument("--obj", type=Path, default=None, help="also write the template OBJ here")
    parser.add_argument("--measure", type=Path, default=None, metavar="REALY_DATA",
                        help="measure the extra points' table on REALY's data/{HIFI3D,BFM09,FLAME}.{obj,txt} "
                        "and compare it with EXTRA_POINTS (writes nothing)")
    args = parser.parse_args(argv)
    if args.measure is not None:
        table = measure(args.measure)
        worst = 0.0
        for index, name, x, y in EXTRA_POINTS:
            mx, my = table[index]
            worst = max(worst, abs(mx - x), abs(my - y))
            print(f"{index} {name}: measured ({mx:+.2f}, {my:+.2f}), EXTRA_POINTS ({x:+.2f}, {y:+.2f})")
        print(f"largest difference from EXTRA_POINTS: {worst:.2f} (eye-corner distances)")
        return

    from facegeo.mesh_io import obj_text
    from facegeo.model_files import load_model

    model = load_model()
    rows = ict_keypoints(model.mean_shape, model.triangles, model.landmark_indices[IBUG68])
    args.output.write_text(json.dumps(rows) + "\n")
    print(f"wrote {args.output} (85 keypoints on {model.name})")
    if args.obj is not None:
        args.obj.write_text(obj_text(model.mean_shape, model.triangles, digits=6, comment=False))
        print(f"wrote {args.obj}")


if __name__ == "__main__":
    main()
