"""UV-space texturing (installed as ``facegeo.texturing``): the texture-backend protocol, the
weight-free default backend, the texture context of a fit, and the differentiable GGX shader of
the paper's appendix A.1. The geometry half (``facegeo``) never imports it; the pipeline does.
"""

from facegeo.texturing.backend import TextureBackend, TextureContext
from facegeo.texturing.default_backend import DefaultBackend
from facegeo.texturing.shading import ShadingResult, shade_ggx

__all__ = ["TextureBackend", "TextureContext", "DefaultBackend", "ShadingResult", "shade_ggx"]
