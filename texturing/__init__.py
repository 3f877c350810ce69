"""UV-space texturing (installed as ``facegeo.texturing``): the texture-backend protocol, the
weight-free default backend, the texture context of a fit, the differentiable GGX shader of
the paper's appendix A.1 and the relit preview that uses it. The geometry half (``facegeo``) never
imports it; the pipeline and the jobs do.

Names are imported lazily (like ``facegeo.uv``'s), so building the CLI's parser, which reads the
backends' names from :mod:`facegeo.texturing.backend`, does not pay for torch and OpenCV.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from facegeo.lazy_exports import lazy_exports

_EXPORTS = {
    "TextureBackend": "facegeo.texturing.backend",
    "TextureContext": "facegeo.texturing.backend",
    "DefaultBackend": "facegeo.texturing.default.backend",
    "ShadingResult": "facegeo.texturing.shading",
    "shade_ggx": "facegeo.texturing.shading",
}

__all__ = list(_EXPORTS)

if TYPE_CHECKING:
    from facegeo.texturing.backend import TextureBackend, TextureContext
    from facegeo.texturing.default.backend import DefaultBackend
    from facegeo.texturing.shading import ShadingResult, shade_ggx


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
