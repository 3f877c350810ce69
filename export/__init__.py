"""Asset export (installed as ``facegeo.export``): subdivision with UVs, displacement, USD, glTF.

Built by the export issue; the geometry half (``facegeo``) never imports it.
"""

__all__: list[str] = []
