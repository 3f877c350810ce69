"""Asset export (installed as ``facegeo.export``): Loop subdivision with face-varying UVs,
displacement baking, USD (usda/usdc/usdz, UsdPreviewSurface) and glTF 2.0 (glb) writers, the
asset folder format, and the animatable face: blendshapes as glTF morph targets and UsdSkel blend
shapes under ARKit's names, driven by Live Link Face takes. Names are imported lazily (USD and glTF libraries load on first use).
"""

from __future__ import annotations

from facegeo.lazy_exports import lazy_exports

_EXPORTS = {
    "subdivide": "facegeo.export.subdivision",
    "displace": "facegeo.export.displacement",
    "bake_displacement": "facegeo.export.displacement",
    "to_trimesh": "facegeo.export.facevarying",
    "from_trimesh": "facegeo.export.facevarying",
    "FaceVaryingMesh": "facegeo.export.facevarying",
    "export_asset": "facegeo.export.writers",
    "FORMATS": "facegeo.export.writers",
    "write_usd": "facegeo.export.usd",
    "validate_usd": "facegeo.export.usd",
    "check_usd": "facegeo.export.usd",
    "write_glb": "facegeo.export.gltf",
    "validate_glb": "facegeo.export.gltf",
    "save_asset": "facegeo.export.asset_io",
    "load_asset": "facegeo.export.asset_io",
    "write_asset_files": "facegeo.export.asset_io",
    "skel_points": "facegeo.export.usd",
    "ARKIT_NAMES": "facegeo.arkit",
    "target_naming": "facegeo.arkit",
    "read_live_link_csv": "facegeo.export.live_link",
    "ArkitTake": "facegeo.arkit",
}

__all__ = list(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
