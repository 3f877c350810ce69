"""The texel sets of a :class:`~facegeo.texturing.backend.TextureContext` and the small ramps that
every stage of the default backend uses: the skin texels, the mirror texel of each texel, an even
subsample of texel indices and the smoothstep ramp.
"""

from __future__ import annotations

import numpy as np

from facegeo.texturing.backend import TextureContext

__all__ = ["mirror_index", "skin_texels", "smoothstep", "subsample"]


def skin_texels(ctx: TextureContext) -> np.ndarray:
    """(S, S) bool: the covered texels that are skin (the context's skin prior > 0.5; every
    covered texel where the context has none)."""
    return ctx.coverage if ctx.skin is None else ctx.coverage & (ctx.skin > 0.5)


def mirror_index(ctx: TextureContext) -> tuple[np.ndarray, np.ndarray]:
    """(S, S) bool: the covered texels that have a mirror texel; (S, S) intp: its flat index into
    an (S·S, …) view (0 where none), so that one gather mirrors a map."""
    has = (ctx.mirror[..., 0] >= 0) & ctx.coverage
    return has, np.where(has, ctx.mirror[..., 0].astype(np.intp) * ctx.size + ctx.mirror[..., 1], 0)


def subsample(rows: np.ndarray, limit: int = 65536) -> np.ndarray:
    """At most ``limit`` evenly spaced entries of the (N,) indices ``rows`` (the light fits' least
    squares of a few coefficients and the fringe's 3 × 3 colour covariance need no more)."""
    return rows if len(rows) <= limit else rows[:: int(np.ceil(len(rows) / limit))]


def smoothstep(t: np.ndarray) -> np.ndarray:
    """3t² − 2t³ of t clipped to [0, 1] (float32, t's shape)."""
    t = np.clip(t, 0.0, 1.0).astype(np.float32)
    return t * t * (3 - 2 * t)
