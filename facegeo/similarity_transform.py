"""The best similarity transform between two point sets (Umeyama 1991): the one implementation
the registration of the dense correspondence and the benchmarks' alignments share."""

from __future__ import annotations

import numpy as np

__all__ = ["similarity_transform"]


def similarity_transform(source: np.ndarray, target: np.ndarray, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R (3, 3), t (3,)) minimising Σ‖s·R·source_i + t − target_i‖², float64; s = 1 when
    ``with_scale`` is False. ``source``, ``target``: (N, 3), N ≥ 3, in the same units."""
    src = np.asarray(source, dtype=np.float64)
    tgt = np.asarray(target, dtype=np.float64)
    ms, mt = src.mean(0), tgt.mean(0)
    a, b = src - ms, tgt - mt
    u, sv, vt = np.linalg.svd(b.T @ a)
    d = np.array([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = (u * d) @ vt
    scale = float((sv * d).sum() / (a**2).sum()) if with_scale else 1.0
    return scale, rotation, mt - scale * rotation @ ms
