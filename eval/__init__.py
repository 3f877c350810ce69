"""Geometry evaluation (installed as ``facegeo.eval``): the REALY protocol.

Built by the REALY issue; the geometry half (``facegeo``) never imports it.
"""

__all__: list[str] = []
