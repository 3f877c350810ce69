"""Files of the REALY protocol: OBJ meshes, barycentric keypoint files, the metrical scales.

The readers follow what the official REALY code reads, because the numbers depend on it. These
are the official reader's quirks, kept on purpose (everything else, finding the ``v`` and ``f``
lines of a file, is :func:`facegeo.mesh_io.obj_records`, and REALY-format files are written with
:func:`facegeo.mesh_io.obj_text`): vertex coordinates are parsed as float64 and stored as
**float32**; a quad ``a b c d`` becomes the triangles ``(a, b, c), (a, c, d)`` in file order;
``f`` tokens may be ``v``, ``v/vt`` or ``v/vt/vn`` (only ``v`` is used; ``vt`` lines are
ignored). Where the official reader would silently do something odd, these raise
:class:`~facegeo.errors.InputError` instead: polygons with more than four corners (the
official reader drops them), non-numeric or non-finite coordinates, and face indices that are
zero, negative or past the last vertex.

A keypoint file is a JSON list of ``[triangle, w0, w1]`` rows: the keypoint is
``w0*a + w1*b + (1-w0-w1)*c`` for the corners ``(a, b, c)`` of that (0-based) triangle.
"""

from __future__ import annotations

import json
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeo.errors import InputError
from facegeo.mesh_io import obj_records

__all__ = [
    "Mesh",
    "read_obj",
    "read_points_obj",
    "read_keypoint_file",
    "barycentric_points",
    "read_metrical_scales",
]


_SLASH_TAIL = re.compile(r"/\S*")  # the vt/vn part of an f token
_NOT_INDEX = re.compile(r"[^0-9\s]")  # anything but unsigned integers and blanks


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh as REALY reads it: float32 vertices, 0-based int64 triangles."""

    vertices: np.ndarray  # (V, 3) float32
    triangles: np.ndarray  # (F, 3) int64, 0-based


def _tokens_per_line(lines: list[str]) -> np.ndarray:
    """(L,) number of blank-separated tokens of each line (``len(line.split())``), vectorised."""
    data = np.frombuffer(("\n".join(lines) + "\n").encode("utf-8", "replace"), dtype=np.uint8)
    gap = (data == 32) | ((data >= 9) & (data <= 13))  # blanks and '\n'
    start = ~gap
    start[1:] &= gap[:-1]
    total = np.cumsum(start, dtype=np.int32)[data == 10]  # tokens up to each line's end
    return np.diff(total, prepend=np.int32(0))


def read_obj(path: str | Path, what: str = "mesh", need_faces: bool = True) -> Mesh:
    """Read an OBJ's ``v`` and ``f`` lines the way the official REALY reader does (see module doc)."""
    path = Path(path)
    records = obj_records(path, what)
    vertices = _parse_vertices(path, what, records["v"])
    faces = _parse_faces_fast(records["f"])
    if faces is None:  # something unusual: line by line, for the message naming the line
        faces = _parse_faces(path, what, records["f"], records["f_line"])
    if need_faces and not len(faces):
        raise InputError(path, what, "a mesh with faces ('f' lines)", "no faces")
    triangles = np.asarray(faces, dtype=np.int64).reshape(-1, 3) - 1
    if triangles.size and (triangles.min() < 0 or triangles.max() >= len(vertices)):
        bad = int(triangles.min() + 1 if triangles.min() < 0 else triangles.max() + 1)
        raise InputError(path, f"{what} faces", f"1-based vertex indices in 1..{len(vertices)}",
                         f"index {bad}")
    return Mesh(vertices, triangles)


def _numbers(text: str, dtype: type) -> np.ndarray | None:
    """Whitespace-separated numbers of ``text`` (None when one does not parse)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a partial parse warns; the caller checks the count
        try:
            return np.fromstring(text, dtype=dtype, sep=" ")
        except ValueError:
            return None


def _parse_faces_fast(face_lines: list[str]) -> np.ndarray | None:
    """(T, 3) 1-based triangles of well-formed ``f`` lines (3 or 4 plain or ``v/vt/vn`` tokens), else None."""
    if not face_lines:
        return np.zeros((0, 3), dtype=np.int64)
    counts = _tokens_per_line(face_lines)
    if not np.all((counts == 3) | (counts == 4)):
        return None
    text = _SLASH_TAIL.sub("", " ".join(face_lines))
    if _NOT_INDEX.search(text):
        return None
    flat = _numbers(text, np.int64)
    if flat is None or len(flat) != counts.sum():
        return None
    start = np.cumsum(counts) - counts
    first = flat[start[:, None] + np.array([0, 1, 2])]
    quad = counts == 4
    second = flat[start[quad, None] + np.array([0, 2, 3])]
    out = np.empty((len(counts) + int(quad.sum()), 3), dtype=np.int64)
    row = np.arange(len(counts)) + np.concatenate([[0], np.cumsum(quad)[:-1]])  # each line's first row
    out[row] = first
    out[row[quad] + 1] = second
    return out


def _parse_faces(path: Path, what: str, rows: list[str], numbers: list[int]) -> list[list[int]]:
    faces: list[list[int]] = []
    for number, raw in zip(numbers, rows):
        tokens = raw.split()
        try:
            idx = [int(t.split("/", 1)[0]) for t in tokens]
        except ValueError:
            raise InputError(path, f"{what} face on line {number}", "integer vertex indices",
                             repr(f"f {raw}".strip()[:60])) from None
        if len(idx) == 3:
            faces.append(idx)
        elif len(idx) == 4:
            faces.append([idx[0], idx[1], idx[2]])
            faces.append([idx[0], idx[2], idx[3]])
        else:
            raise InputError(path, f"{what} face on line {number}", "a triangle or a quad",
                             f"a face with {len(idx)} corners")
    return faces


def _parse_vertices(path: Path, what: str, lines: list[str]) -> np.ndarray:
    if not lines:
        raise InputError(path, what, "vertices ('v' lines)", "none")
    arr = None
    per_line = set(np.unique(_tokens_per_line(lines)).tolist())
    if len(per_line) == 1 and (k := per_line.pop()) >= 3:  # every line 'v' + k numbers
        flat = _numbers(" ".join(lines), np.float64)
        if flat is not None and len(flat) == k * len(lines):
            arr = flat.reshape(-1, k)[:, :3]
    if arr is None:
        try:
            arr = np.array([[float(t) for t in line.split()[:3]] for line in lines], dtype=np.float64)
        except ValueError:
            raise InputError(path, f"{what} vertices", "'v x y z' lines with numbers", "a malformed line") from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(path, f"{what} vertices", "'v x y z' lines with three coordinates", "fewer")
    vertices = arr.astype(np.float32)
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        first = int(np.argmin(finite))
        raise InputError(path, f"{what} vertices", "finite coordinates",
                         f"{int((~finite).sum())} vertices with NaN or infinity (first: vertex {first + 1})")
    return vertices


def read_points_obj(path: str | Path, what: str = "keypoints", count: int | None = None) -> np.ndarray:
    """The ``v`` lines of an OBJ as (N, 3) float32 (REALY's per-subject keypoint files)."""
    path = Path(path)
    points = _parse_vertices(path, what, obj_records(path, what)["v"])
    if count is not None and len(points) != count:
        raise InputError(path, what, f"{count} points", str(len(points)))
    return points


def read_keypoint_file(path: str | Path, n_triangles: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(triangle indices (85,), corner weights (85, 3) float64) from a barycentric keypoint file."""
    path = Path(path)
    try:
        rows = json.loads(path.read_text(encoding="utf-8"))
        table = np.array(rows, dtype=np.float64)
    except FileNotFoundError:
        raise InputError(path, "keypoint file", "an existing barycentric keypoint file", "no such file") from None
    except (OSError, ValueError, TypeError) as exc:
        raise InputError(path, "keypoint file", "a JSON list of [triangle, w0, w1] rows",
                         type(exc).__name__) from None
    if table.ndim != 2 or table.shape != (85, 3):
        raise InputError(path, "keypoint file", "85 rows of [triangle, w0, w1]", f"shape {table.shape}")
    if not np.isfinite(table).all():
        raise InputError(path, "keypoint file", "finite numbers", "NaN or infinity")
    tri = table[:, 0]
    if np.any(tri != np.round(tri)) or tri.min() < 0:
        raise InputError(path, "keypoint file", "non-negative integer triangle indices", "other values")
    tri = tri.astype(np.int64)
    if n_triangles is not None and tri.max() >= n_triangles:
        raise InputError(path, "keypoint file", f"triangle indices below {n_triangles} (the topology's triangles)",
                         f"index {int(tri.max())}")
    weights = np.stack([table[:, 1], table[:, 2], 1.0 - table[:, 1] - table[:, 2]]).T
    return tri, weights


def barycentric_points(vertices: np.ndarray, triangles: np.ndarray, tri: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Keypoints of a mesh, computed exactly as the official code does (float64 result)."""
    corners = vertices[triangles[tri]]  # (85, 3, 3) in the vertices' dtype
    return np.sum(corners * weights.reshape(-1, 3, 1), axis=1)


def read_metrical_scales(path: str | Path) -> np.ndarray:
    """REALY's ``metrical_scale.txt``: one number per subject, subject ``k`` on line ``k``."""
    path = Path(path)
    try:
        scales = np.loadtxt(path, dtype=np.float64, ndmin=1)
    except FileNotFoundError:
        raise InputError(path, "metrical scale file", "an existing file", "no such file") from None
    except (OSError, ValueError) as exc:
        raise InputError(path, "metrical scale file", "one number per line", type(exc).__name__) from None
    if scales.ndim != 1 or not np.isfinite(scales).all() or np.any(scales <= 0):
        raise InputError(path, "metrical scale file", "one positive number per line", "other values")
    return scales
