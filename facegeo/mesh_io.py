"""Wavefront OBJ reading and writing for the project (REALY's reader, with the official reader's
quirks, is :mod:`facegeo.eval.realy_io`; it reads its lines with :func:`obj_records`).

Written by hand rather than through trimesh: trimesh splits vertices along UV seams on export,
which would break the one-to-one vertex order that REALY keypoint files and the model's landmark
indices rely on. Here ``v`` lines keep the model's vertex order, ``vt`` lines the UV list (origin
bottom-left, as OBJ and DESIGN.md), and faces reference both (``f v/vt``), 1-based as the format
requires.
"""

from __future__ import annotations

import hashlib
import io
import os
from pathlib import Path

import numpy as np

from facegeo.errors import InputError

__all__ = ["obj_text", "obj_records", "read_obj"]

#: The first line of the meshes facegeo writes.
OBJ_COMMENT = "# facegeo mesh: millimetres, +Y up, +Z out of the face\n"


def obj_text(vertices: np.ndarray, triangles: np.ndarray | None = None, uv: np.ndarray | None = None,
             uv_triangles: np.ndarray | None = None, *, digits: int = 5, comment: bool = True, quads: bool = False) -> str:
    """The OBJ text of a mesh.

    Args:
        vertices: (V, 3) vertices (mm), written with ``digits`` decimals.
        triangles: (F, 3) 0-based triangles, or None (a point set: ``v`` lines only).
        uv, uv_triangles: optional (T, 2) UVs (6 decimals) and their (F, 3) triangles (``f v/vt``).
        comment: start with :data:`OBJ_COMMENT`.
        quads: write consecutive triangle pairs ``(a, b, c), (a, c, d)`` as the quad ``a b c d``
            (which reads back to the same two triangles); not with UVs.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    out = io.StringIO()
    if comment:
        out.write(OBJ_COMMENT)
    out.write(_lines(f"v %.{digits}f %.{digits}f %.{digits}f", vertices))
    if triangles is None:
        return out.getvalue()
    if uv is not None and uv_triangles is not None:
        out.write(_layout_lines(np.asarray(triangles, dtype=np.int64), np.asarray(uv, dtype=np.float64),
                                np.asarray(uv_triangles, dtype=np.int64)))
        return out.getvalue()
    t = np.asarray(triangles, dtype=np.int64) + 1
    if quads:
        i = 0
        while i < len(t):
            a, b, c = t[i]
            if i + 1 < len(t) and t[i + 1][0] == a and t[i + 1][1] == c:
                out.write(f"f {a} {b} {c} {t[i + 1][2]}\n")
                i += 2
                continue
            out.write(f"f {a} {b} {c}\n")
            i += 1
    else:
        out.write(_lines("f %d %d %d", t))
    return out.getvalue()


def _layout_lines(triangles: np.ndarray, uv: np.ndarray, uv_triangles: np.ndarray) -> str:
    """The ``vt`` lines of ``uv`` (T, 2) float64 and the ``f v/vt`` lines of ``triangles`` and
    ``uv_triangles`` (F, 3) int64: text that every mesh of a model shares, so it is kept in the
    layout cache (:mod:`facegeo.layout_cache`), keyed by a digest of the three arrays. For the
    bundled model, formatting it took 12-14 ms a mesh, reading it back takes 1-2 ms."""
    from facegeo.layout_cache import entry_folder, load_or_make

    digest = hashlib.blake2b(digest_size=16)
    for array in (triangles, uv, uv_triangles):
        digest.update(repr(array.shape).encode("ascii"))
        digest.update(np.ascontiguousarray(array).tobytes())

    def make() -> str:
        faces = np.stack([triangles + 1, uv_triangles + 1], axis=-1).reshape(-1, 6)
        return _lines("vt %.6f %.6f", uv) + _lines("f %d/%d %d/%d %d/%d", faces)

    return load_or_make(entry_folder(f"obj-layout-{digest.hexdigest()}"), lambda arrays, meta: arrays["text"].tobytes().decode("ascii"),
                        make, lambda text: ({"text": np.frombuffer(text.encode("ascii"), dtype=np.uint8)}, {}))


def _lines(fmt: str, rows: np.ndarray) -> str:
    """``fmt % row`` for each row of a 2-D array, one line each: the text ``np.savetxt`` writes,
    formatted in one ``%`` operation (about 4x faster than its row-by-row loop)."""
    return ((fmt + "\n") * len(rows)) % tuple(rows.ravel().tolist())


def obj_records(path: str | os.PathLike[str], what: str = "mesh") -> dict[str, list]:
    """The ``v``, ``vt`` and ``f`` lines of an OBJ file without their keyword (``{"v": [...],
    "vt": [...], "f": [...]}``, in file order) and ``"f_line"``, the 1-based line number of each
    ``f`` line (for messages); lines are split as ``str.splitlines`` does, bytes that are not UTF-8
    are replaced. Raises :class:`InputError` (naming ``what``) for a missing or unreadable file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        raise InputError(p, what, "an existing OBJ file", "no such file") from None
    except OSError as exc:
        raise InputError(p, what, "a readable OBJ file", exc.strerror or str(exc)) from None
    records: dict[str, list] = {"v": [], "vt": [], "f": [], "f_line": []}
    for number, line in enumerate(text.splitlines(), 1):
        if line.startswith("v "):
            records["v"].append(line[2:])
        elif line.startswith("vt "):
            records["vt"].append(line[3:])
        elif line.startswith("f "):
            records["f"].append(line[2:])
            records["f_line"].append(number)
    return records


def read_obj(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Read a triangle OBJ: ``(vertices (V, 3) float64, triangles (F, 3), uv (T, 2) | None,
    uv_triangles (F, 3) | None)``. Faces are ``f v``, ``f v/vt`` or ``f v/vt/vn`` (1-based or
    negative indices); normals, groups and materials are ignored.

    Raises:
        InputError: a missing file, a polygon that is not a triangle, or malformed numbers.
    """
    p = Path(path)
    records = obj_records(p)
    v_rows, vt_rows, f_rows = records["v"], records["vt"], records["f"]
    try:
        vertices = np.array([row.split()[:3] for row in v_rows], dtype=np.float64).reshape(-1, 3)
        uv = np.array([row.split()[:2] for row in vt_rows], dtype=np.float64).reshape(-1, 2) if vt_rows else None
    except ValueError as exc:
        raise InputError(p, "v/vt", "numbers", str(exc)) from None
    if len(vertices) == 0 or not f_rows:
        raise InputError(p, "mesh", "vertices (v) and faces (f)", f"{len(vertices)} vertices, {len(f_rows)} faces")
    corners = []
    for k, row in enumerate(f_rows):
        parts = row.split()
        if len(parts) != 3:
            raise InputError(p, f"face {k + 1}", "a triangle", f"{len(parts)} corners")
        corners.append([c.split("/") for c in parts])
    try:
        vi = np.array([[int(c[0]) for c in face] for face in corners], dtype=np.int64)
        has_vt = uv is not None and all(len(c) > 1 and c[1] for face in corners for c in face)
        ti = np.array([[int(c[1]) for c in face] for face in corners], dtype=np.int64) if has_vt else None
    except ValueError as exc:
        raise InputError(p, "f", "integer indices", str(exc)) from None
    triangles = np.where(vi < 0, vi + len(vertices), vi - 1)
    if triangles.min() < 0 or triangles.max() >= len(vertices):
        raise InputError(p, "f", f"vertex indices in [1, {len(vertices)}]")
    if ti is None:
        return vertices, triangles, None, None
    uv_triangles = np.where(ti < 0, ti + len(uv), ti - 1)
    if uv_triangles.min() < 0 or uv_triangles.max() >= len(uv):
        raise InputError(p, "f", f"texture indices in [1, {len(uv)}]")
    return vertices, triangles, uv, uv_triangles
