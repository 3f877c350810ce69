"""UV-space texturing (installed as ``facegeo.texturing``): texture backends and the GGX shader.

Built by the texturing issue; the geometry half (``facegeo``) never imports it.
"""

__all__: list[str] = []
