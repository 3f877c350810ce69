"""Wavefront OBJ output of a model mesh with its face-varying UVs.

Written by hand rather than through trimesh: trimesh splits vertices along UV seams on export,
which would break the one-to-one vertex order that REALY keypoint files and the model's landmark
indices rely on. Here ``v`` lines keep the model's vertex order, ``vt`` lines the UV list, and
faces reference both (``f v/vt``), 1-based as the format requires.
"""

from __future__ import annotations

import io

import numpy as np


__all__ = ["obj_text"]


def obj_text(vertices: np.ndarray, triangles: np.ndarray, uv: np.ndarray | None = None, uv_triangles: np.ndarray | None = None) -> str:
    """The OBJ text of (V, 3) mm vertices, (F, 3) triangles and optional (T, 2) UVs (origin
    bottom-left, as OBJ) with (F, 3) UV triangles."""
    vertices = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64)
    out = io.StringIO()
    out.write("# facegeo mesh: millimetres, +Y up, +Z out of the face\n")
    np.savetxt(out, vertices, fmt="v %.5f %.5f %.5f")
    if uv is not None and uv_triangles is not None:
        np.savetxt(out, np.asarray(uv, dtype=np.float64), fmt="vt %.6f %.6f")
        faces = np.stack([triangles + 1, np.asarray(uv_triangles, dtype=np.int64) + 1], axis=-1).reshape(-1, 6)
        np.savetxt(out, faces, fmt="f %d/%d %d/%d %d/%d")
    else:
        np.savetxt(out, triangles + 1, fmt="f %d %d %d")
    return out.getvalue()

