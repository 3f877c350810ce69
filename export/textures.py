"""What a material uses, and map encodings (PNG 8/16-bit with scale and offset).

:func:`material_inputs` decides, for the maps a scene is asked to carry, which become textures
and which become factors: a map given as a constant, or whose texels are all equal within half an
8-bit step (displacement: 1 µm), is a factor; a map not asked for is not written at all.

Encodings (value = offset + scale × texel / (2^bits − 1)):

============== ====== ======== =====================================================
map            bits   colour   stored texel
============== ====== ======== =====================================================
albedo         8      sRGB     the sRGB value (scale 1, offset 0)
normal         8/16   linear   n·0.5 + 0.5 (scale 2, offset −1), OpenGL +Y
roughness      8/16   linear   the value
specular       8/16   linear   the value (F0 = 0.08 × value)
displacement   16     linear   (d − min)/(max − min): scale = max − min mm, offset = min mm
============== ====== ======== =====================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np

from facegeo.asset import MAP_CHANNELS, MAP_NAMES, Asset
from facegeo.errors import InputError
from facegeo.image_files import to_uint

__all__ = [
    "MaterialInput",
    "material_inputs",
    "DEFAULT_ROUGHNESS",
    "encode_map",
    "decode_map",
]

#: Roughness written when the asset has none (UsdPreviewSurface's default; glTF's is 1.0, so the
#: glTF writer writes it explicitly).
DEFAULT_ROUGHNESS = 0.5

_FLAT_TOLERANCE = {"albedo": 0.5 / 255, "normal": 0.5 / 255, "roughness": 0.5 / 255, "specular": 0.5 / 255, "displacement": 1e-3}


@dataclass
class MaterialInput:
    """One material input: either ``texture`` (the map array, as in the Asset) or ``value`` (a
    float, or an RGB triple; albedo values are sRGB-encoded as in the Asset)."""

    name: str
    texture: np.ndarray | None = None
    value: Any = None

    @property
    def is_texture(self) -> bool:
        return self.texture is not None


def material_inputs(asset: Asset, maps: Iterable[str] | None = None) -> dict[str, MaterialInput]:
    """The material inputs a scene of ``asset`` carries, in MAP_NAMES order.

    ``maps``: the names asked for (default: every map and constant of the asset). A name asked
    for that the asset has neither as a map nor as a constant raises :class:`InputError`. Uniform
    maps become values; a normal map that is uniformly +Z (or a +Z constant) is dropped, since it
    changes nothing.
    """
    available = set(asset.maps) | set(asset.constants)
    if maps is None:
        wanted = [m for m in MAP_NAMES if m in available]
    else:
        wanted = list(dict.fromkeys(maps))
        for name in wanted:
            if name not in MAP_CHANNELS:
                raise InputError("<export>", "maps", f"names among {', '.join(MAP_NAMES)}", repr(name))
            if name not in available:
                raise InputError("<export>", "maps", f"maps the asset has ({', '.join(m for m in MAP_NAMES if m in available) or 'none'})", repr(name))
        wanted = [m for m in MAP_NAMES if m in wanted]
    out: dict[str, MaterialInput] = {}
    for name in wanted:
        if name in asset.constants:
            value = asset.constants[name]
            value = tuple(float(x) for x in value) if np.ndim(value) else float(value)
            item = MaterialInput(name, value=value)
        else:
            array = asset.maps[name]
            flat = array.reshape(-1, MAP_CHANNELS[name])
            if np.all(flat.max(axis=0) - flat.min(axis=0) <= _FLAT_TOLERANCE[name]):
                mean = flat.mean(axis=0)
                item = MaterialInput(name, value=float(mean[0]) if MAP_CHANNELS[name] == 1 else tuple(float(x) for x in mean))
            else:
                item = MaterialInput(name, texture=array)
        if name == "normal" and not item.is_texture:
            n = np.asarray(item.value, dtype=np.float64)
            if np.linalg.norm(n / max(np.linalg.norm(n), 1e-12) - [0.0, 0.0, 1.0]) < 1e-3:
                continue
            item = MaterialInput(name, texture=np.broadcast_to(np.asarray(item.value, np.float32), (4, 4, 3)).copy())
        out[name] = item
    return out


def encode_map(name: str, array: np.ndarray, bits: int | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Encode a map for a PNG: returns ``(uint8/uint16 image, encoding)`` where ``encoding`` is
    ``{"bits", "colorspace", "scale", "offset"}`` with value = offset + scale × texel/(2^bits − 1)
    (per channel for the normal map: scale 2, offset −1)."""
    a = np.asarray(array, dtype=np.float64)
    if bits is None:
        bits = 16 if name == "displacement" else 8
    if bits not in (8, 16):
        raise ValueError(f"bits must be 8 or 16, got {bits}")
    colorspace = "srgb" if name == "albedo" else "linear"
    if name == "normal":
        n = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
        return to_uint(n * 0.5 + 0.5, bits), {"bits": bits, "colorspace": colorspace, "scale": 2.0, "offset": -1.0}
    if name == "displacement":
        lo, hi = float(a.min()), float(a.max())
        scale = hi - lo
        unit = (a - lo) / scale if scale > 0 else np.zeros_like(a)
        return to_uint(unit, bits), {"bits": bits, "colorspace": colorspace, "scale": scale, "offset": lo}
    return to_uint(a, bits), {"bits": bits, "colorspace": colorspace, "scale": 1.0, "offset": 0.0}


def decode_map(name: str, image: np.ndarray, encoding: dict[str, Any]) -> np.ndarray:
    """Inverse of :func:`encode_map`: float32 values (normals re-normalised)."""
    top = float((1 << int(encoding["bits"])) - 1)
    values = float(encoding["offset"]) + float(encoding["scale"]) * (np.asarray(image, dtype=np.float64) / top)
    if name == "normal":
        values = values / np.maximum(np.linalg.norm(values, axis=-1, keepdims=True), 1e-12)
    return values.astype(np.float32)
