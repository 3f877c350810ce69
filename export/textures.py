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

:class:`TextureFiles` makes the PNG file of each map encoding once per export and shares it
between the asset folder and every scene format that embeds it.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np

from facegeo.asset import MAP_CHANNELS, MAP_NAMES, Asset
from facegeo.errors import InputError
from facegeo.image_files import plain_png, png_bytes, to_uint

__all__ = [
    "MaterialInput",
    "material_inputs",
    "DEFAULT_ROUGHNESS",
    "encode_map",
    "decode_map",
    "TextureFiles",
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
            if _uniform(flat, _FLAT_TOLERANCE[name]):
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


def _uniform(flat: np.ndarray, tolerance: float) -> bool:
    """Whether each channel of the (N, C) texels ``flat`` spans at most ``tolerance``: judged
    first on every 64th texel (a span found there is in the whole; a textured map, the usual
    case, is told from it at once: a channel's min and max over a whole 1K map took 11 ms each,
    for every map of every scene), then on all."""
    sample = flat[::64]
    if np.any(sample.max(axis=0) - sample.min(axis=0) > tolerance):
        return False
    return bool(np.all(flat.max(axis=0) - flat.min(axis=0) <= tolerance))


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


class TextureFiles:
    """The PNG files of one export's map textures, each made once and shared by every writer given
    this object (``facegeo reconstruct``: the asset folder, the usdz and the glb all carry the
    8-bit albedo; both scenes the 8-bit normal map).

    :meth:`map_png` is :func:`encode_map` followed by :func:`facegeo.image_files.png_bytes`,
    remembered per (map name, bits, map array): the key is the array object itself (kept alive
    here, so that its ``id`` is not reused), so the maps must not be changed in place while the
    object is in use: one export.
    Thread-safe: a writer asking for a file another thread is making waits for it.

    :meth:`add_file` offers a PNG file already on disk (``facegeo export`` reads an asset folder):
    a map encoded to exactly that file's pixels is given the file's bytes instead of a new
    encoding, when the file is plain (:func:`facegeo.image_files.plain_png`).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._made: dict[tuple[str, int, int], tuple[np.ndarray, Future[tuple[bytes, dict[str, Any]]]]] = {}
        self._on_disk: dict[int, tuple[np.ndarray, np.ndarray, bytes]] = {}
        #: PNG encodings made (files taken from disk not counted).
        self.encoded = 0

    def add_file(self, array: np.ndarray, image: np.ndarray, data: bytes) -> None:
        """Offer ``data``, a PNG file whose pixels are ``image`` ((H, W[, C]) uint8/uint16 RGB(A),
        as :func:`facegeo.image_files.read_png_file` gives them), for the map ``array`` decoded
        from it; ignored unless the file is plain."""
        if plain_png(data):
            with self._lock:
                self._on_disk[id(array)] = (array, image, data)

    def map_png(self, name: str, array: np.ndarray, bits: int) -> tuple[bytes, dict[str, Any]]:
        """``(PNG bytes, encoding)`` of ``encode_map(name, array, bits)``, made on the first call
        for this map and encoding and given again to every later one."""
        key = (name, bits, id(array))
        with self._lock:
            entry = self._made.get(key)
            owner = entry is None
            if owner:
                entry = self._made[key] = (array, Future())
        assert entry is not None
        if not owner:
            return entry[1].result()
        try:
            image, encoding = encode_map(name, array, bits)
            data = self._file_on_disk(array, image)
            if data is None:
                data = png_bytes(image)
                with self._lock:
                    self.encoded += 1
        except BaseException as exc:
            entry[1].set_exception(exc)
            with self._lock:
                del self._made[key]
            raise
        entry[1].set_result((data, encoding))
        return data, encoding

    def _file_on_disk(self, array: np.ndarray, image: np.ndarray) -> bytes | None:
        """The bytes of the file offered for ``array`` when its pixels are ``image``, else None."""
        with self._lock:
            offered = self._on_disk.get(id(array))
        if offered is None:
            return None
        _, pixels, data = offered
        return data if pixels.dtype == image.dtype and np.array_equal(pixels, image) else None
