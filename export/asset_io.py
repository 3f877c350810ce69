"""Saving an :class:`~facegeo.asset.Asset` to a folder and loading it back (for ``facegeo export``).

The folder::

    asset.json        format, version, name, units, the mesh file, per map its file and encoding,
                      constants, metadata
    mesh.obj          v (mm, model vertex order), vt (origin bottom-left), f v/vt (face-varying UVs)
    albedo.png        8-bit sRGB
    normal.png        16-bit, n·0.5 + 0.5 (scale 2, offset −1)
    roughness.png     16-bit
    specular.png      16-bit
    displacement.png  16-bit, value = offset + scale × texel/65535 (mm)
    parts/<part>_mesh.obj, parts/<part>_<map>.png
                      each part (eyeballs, teeth, ...) with its own mesh, maps and constants
    blendshapes.npz   the expression blendshapes of the skin and of the parts they move (when
                      the asset has them): per surface the nonzero (shape, vertex, delta mm)
                      triples (float16 when that loses nothing, as for ICT-FaceKit's shapes)

``asset.json`` lists the parts as ``"parts": [{"name", "mesh", "maps", "constants"}]`` and the
face region as ``"face_triangles": [[start, stop], ...]`` (triangle index ranges), the
blendshapes as ``"blendshapes": {"file", "names", "weights", "surfaces"}`` (the shapes' names,
the fitted weights, and which surfaces have shapes: ``""`` for the skin, else the part's name).

Each map entry of ``asset.json`` is ``{"file", "bits", "colorspace", "scale", "offset",
"shape"}`` (see :mod:`facegeo.export.textures`); the value of a texel is
``offset + scale × texel / (2^bits − 1)``. A 16-bit PNG keeps linear data to 1/65535 of its
range (a 2 mm displacement range: 0.03 µm steps); albedo, 8-bit sRGB, loses nothing a renderer
would show.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from facegeo.asset import MAP_CHANNELS, MAP_NAMES, Asset
from facegeo.blendshapes import Blendshapes
from facegeo.errors import InputError
from facegeo.export.textures import TextureFiles, decode_map
from facegeo.image_files import read_png_file
from facegeo.mesh_io import obj_text, read_obj
from facegeo.staged_output import StagedOutput

__all__ = ["save_asset", "write_asset_files", "write_asset_geometry", "load_asset", "ASSET_FILE", "ASSET_FORMAT", "ASSET_VERSION"]

ASSET_FILE = "asset.json"
ASSET_FORMAT = "facegeo-asset"
ASSET_VERSION = 1
_MESH_FILE = "mesh.obj"
_PARTS_DIR = "parts"
_BLENDSHAPES_FILE = "blendshapes.npz"


def save_asset(asset: Asset, folder: str | os.PathLike[str], *, linear_bits: int = 16) -> Path:
    """Write ``asset`` into ``folder`` (created) atomically: on failure nothing is left. Files
    already in the folder that the asset does not write are kept. Returns the folder."""
    with StagedOutput(folder) as stage:
        write_asset_files(asset, stage.staging_dir, linear_bits=linear_bits)
    return Path(folder)


def write_asset_files(asset: Asset, folder: str | os.PathLike[str], *, linear_bits: int = 16,
                      texture_files: TextureFiles | None = None, geometry_record: dict[str, Any] | None = None) -> dict[str, Any]:
    """Write the asset's files into an existing ``folder`` (not atomic: for use inside a
    :class:`~facegeo.staged_output.StagedOutput`). ``texture_files``: the maps' PNG files shared
    with the scenes written beside the folder (default: made here). ``geometry_record``: what
    :func:`write_asset_geometry` returned for this asset's geometry in this folder (those files
    are then not written again). Returns the ``asset.json`` content."""
    if not isinstance(asset, Asset):
        raise InputError("<asset>", "asset", "a facegeo.asset.Asset", type(asset).__name__)
    asset.validate()  # again: the maps may have been changed since construction
    out = Path(folder)
    files = TextureFiles() if texture_files is None else texture_files
    if geometry_record is None:
        geometry_record = write_asset_geometry(asset, out, linear_bits=linear_bits, texture_files=files)
    doc: dict[str, Any] = {
        "format": ASSET_FORMAT,
        "version": ASSET_VERSION,
        "name": asset.name,
        "units": "mm",
        "up_axis": "Y",
        "uv_origin": "bottom-left",
        "mesh": _MESH_FILE,
        "maps": _write_maps(asset, out, "", linear_bits, files),
        "constants": _constants(asset),
        **geometry_record,
    }
    doc["metadata"] = asset.metadata
    try:
        text = json.dumps(doc, indent=1, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise InputError("<asset>", "metadata", "JSON-ready values (numbers, strings, lists, dicts)", str(exc)) from None
    (out / ASSET_FILE).write_text(text)
    return doc


def write_asset_geometry(asset: Asset, folder: str | os.PathLike[str], *, linear_bits: int = 16,
                         texture_files: TextureFiles | None = None) -> dict[str, Any]:
    """Write what of the asset folder does not depend on the skin's maps, constants or metadata
    into an existing ``folder``: ``mesh.obj``, the parts (meshes and maps) and
    ``blendshapes.npz`` (``facegeo reconstruct`` writes them while the texture stages run).
    Returns their ``asset.json`` records (``face_triangles``, ``parts``, ``blendshapes``) for
    :func:`write_asset_files`."""
    out = Path(folder)
    files = TextureFiles() if texture_files is None else texture_files
    (out / _MESH_FILE).write_text(obj_text(asset.vertices, asset.triangles, asset.uv, asset.uv_triangles))
    record: dict[str, Any] = {}
    if asset.face_triangles is not None:
        record["face_triangles"] = _ranges(asset.face_triangles)
    if asset.parts:
        (out / _PARTS_DIR).mkdir(exist_ok=True)
        record["parts"] = [{"name": part.name, **_write_surface(part, out, f"{_PARTS_DIR}/{part.name}_", linear_bits, files)}
                           for part in asset.parts]
    shaped = [("", asset.blendshapes)] + [(part.name, part.blendshapes) for part in asset.parts]
    shaped = [(surface, shapes) for surface, shapes in shaped if shapes is not None]
    if shaped:
        first = shaped[0][1]
        record["blendshapes"] = {"file": _BLENDSHAPES_FILE, "names": list(first.names),
                                 "weights": [float(w) for w in first.weights], "surfaces": [surface for surface, _ in shaped]}
        _write_blendshapes(out / _BLENDSHAPES_FILE, shaped)
    return record


def _write_maps(asset: Asset, out: Path, prefix: str, linear_bits: int, files: TextureFiles) -> dict[str, Any]:
    """Write one surface's maps as ``<prefix><map>.png``; returns their records."""
    maps: dict[str, Any] = {}
    for name in MAP_NAMES:
        if name not in asset.maps:
            continue
        bits = 8 if name == "albedo" else linear_bits
        data, encoding = files.map_png(name, asset.maps[name], bits)
        file = f"{prefix}{name}.png"
        (out / file).write_bytes(data)
        maps[name] = {"file": file, **encoding, "shape": list(asset.maps[name].shape)}
    return maps


def _constants(asset: Asset) -> dict[str, Any]:
    return {k: (list(map(float, v)) if np.ndim(v) else float(v)) for k, v in asset.constants.items()}


def _write_surface(asset: Asset, out: Path, prefix: str, linear_bits: int, files: TextureFiles) -> dict[str, Any]:
    """Write one part's mesh and maps as ``<prefix>mesh.obj``, ``<prefix><map>.png``; returns
    its ``mesh``, ``maps`` and ``constants`` records."""
    maps = _write_maps(asset, out, prefix, linear_bits, files)
    mesh = f"{prefix}{_MESH_FILE}"
    (out / mesh).write_text(obj_text(asset.vertices, asset.triangles, asset.uv, asset.uv_triangles))
    return {"mesh": mesh, "maps": maps, "constants": _constants(asset)}


#: The last ``blendshapes.npz`` made in this process: (digest of what it holds, its bytes). The
#: blendshapes are the model's, the same for every photo fitted with it: a batch worker's items
#: after its first write the file again without making it (88 ms a face, the digest 10 ms).
_LAST_BLENDSHAPES: tuple[bytes, bytes] | None = None


def _write_blendshapes(path: Path, shaped: list[tuple[str, Blendshapes]]) -> None:
    """``blendshapes.npz``: per surface (key prefix ``<surface>__``, ``skin`` for the skin) the
    shape and vertex index and the (n, 3) delta of every nonzero delta. Deflated at level 1 (a
    third of the time of NumPy's default level for 6 % more bytes)."""
    global _LAST_BLENDSHAPES
    digest = hashlib.blake2b(digest_size=16)
    for surface, shapes in shaped:
        deltas = np.ascontiguousarray(shapes.deltas)
        digest.update(repr((surface, tuple(shapes.names), deltas.shape, deltas.dtype.str)).encode())
        digest.update(deltas.data)
    key = digest.digest()
    last = _LAST_BLENDSHAPES
    if last is None or last[0] != key:
        last = _LAST_BLENDSHAPES = (key, _blendshapes_file(shaped))
    path.write_bytes(last[1])


def _blendshapes_file(shaped: list[tuple[str, Blendshapes]]) -> bytes:
    """The bytes of :func:`_write_blendshapes`' file."""
    arrays: dict[str, np.ndarray] = {}
    for surface, shapes in shaped:
        key = surface or "skin"
        shape, vertex = np.nonzero(np.any(shapes.deltas != 0, axis=2))
        delta = shapes.deltas[shape, vertex]
        half = delta.astype(np.float16)
        lossless = np.all(np.isfinite(half)) and np.array_equal(half.astype(np.float32), delta)
        arrays[f"{key}__shape"] = shape.astype(np.int32)
        arrays[f"{key}__vertex"] = vertex.astype(np.int32)
        arrays[f"{key}__delta"] = half if lossless else delta
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
        for name, array in arrays.items():
            with archive.open(f"{name}.npy", "w") as member:
                np.lib.format.write_array(member, array, allow_pickle=False)
    return buffer.getvalue()


def _read_blendshapes(root: Path, meta_path: Path, doc: dict[str, Any], surfaces: dict[str, int]) -> dict[str, Blendshapes]:
    """The :class:`Blendshapes` of each surface named in ``doc["blendshapes"]``; ``surfaces``:
    surface name -> its vertex count."""
    record = doc.get("blendshapes")
    if record is None:
        return {}
    try:
        names = tuple(str(n) for n in record["names"])
        weights = np.asarray(record["weights"], dtype=np.float32)
        listed = [str(s) for s in record["surfaces"]]
        file = root / str(record["file"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(meta_path, "blendshapes", "file, names, weights and surfaces", str(exc)) from None
    if weights.shape != (len(names),) or not np.all(np.isfinite(weights)):
        raise InputError(meta_path, "blendshapes.weights", f"{len(names)} finite numbers", str(weights.shape))
    if not file.is_file():
        raise InputError(file, "blendshapes", "the blendshapes file", "no such file")
    out = {}
    try:
        with np.load(file) as data:
            for surface in listed:
                if surface not in surfaces:
                    raise InputError(meta_path, "blendshapes.surfaces", "the skin (\"\") or a part's name", repr(surface))
                key = surface or "skin"
                shape, vertex = data[f"{key}__shape"].astype(np.int64), data[f"{key}__vertex"].astype(np.int64)
                delta = data[f"{key}__delta"].astype(np.float32)
                n_vertices = surfaces[surface]
                if len(shape) != len(vertex) or delta.shape != (len(shape), 3) or (len(shape) and (
                        shape.min() < 0 or shape.max() >= len(names) or vertex.min() < 0 or vertex.max() >= n_vertices)):
                    raise InputError(file, f"{key}", f"shape indices < {len(names)}, vertex indices < {n_vertices}, (n, 3) deltas",
                                     f"{len(shape)} shapes, {len(vertex)} vertices, deltas {delta.shape}")
                deltas = np.zeros((len(names), n_vertices, 3), np.float32)
                deltas[shape, vertex] = delta
                out[surface] = Blendshapes(names, deltas, weights.copy())
    except KeyError as exc:
        raise InputError(file, str(exc).strip("'\""), "the surface's shape, vertex and delta arrays", "missing") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:  # unreadable, truncated or corrupt
        raise InputError(file, "blendshapes", "an .npz file written by facegeo", f"{type(exc).__name__}: {exc}") from None
    return out


def _ranges(mask: np.ndarray) -> list[list[int]]:
    """[[start, stop), ...] of the True runs of a bool array (compact in JSON: ICT's face region is one run)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return edges.reshape(-1, 2).tolist()


def load_asset(folder: str | os.PathLike[str], *, texture_files: TextureFiles | None = None) -> Asset:
    """Read an asset folder written by :func:`save_asset`. ``texture_files``: offered the map
    files as they are (:meth:`TextureFiles.add_file`), so that a writer given it embeds a file
    whose pixels it would encode instead of encoding them again.

    Raises:
        InputError: naming the file and field for a missing folder or file, a malformed
            ``asset.json``, an unreadable image or a map whose shape disagrees with the record.
    """
    root = Path(folder)
    meta_path = root / ASSET_FILE
    if not root.is_dir():
        raise InputError(root, "asset folder", f"a folder with {ASSET_FILE}, mesh.obj and the maps", "no such folder")
    if not meta_path.is_file():
        raise InputError(meta_path, ASSET_FILE, "an asset description written by facegeo", "no such file")
    try:
        doc = json.loads(meta_path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(meta_path, ASSET_FILE, "valid JSON", str(exc)) from None
    if not isinstance(doc, dict) or doc.get("format") != ASSET_FORMAT:
        raise InputError(meta_path, "format", repr(ASSET_FORMAT), repr(doc.get("format") if isinstance(doc, dict) else doc))
    if doc.get("version") != ASSET_VERSION:
        raise InputError(meta_path, "version", str(ASSET_VERSION), repr(doc.get("version")))
    part_surfaces = []
    records = doc.get("parts", []) or []
    if not isinstance(records, list):
        raise InputError(meta_path, "parts", "a list of part records")
    for k, rec in enumerate(records):
        if not isinstance(rec, dict) or not isinstance(rec.get("name"), str):
            raise InputError(meta_path, f"parts[{k}]", "a record with a name, mesh, maps and constants")
        part_surfaces.append((rec["name"], _read_surface(root, meta_path, rec, f"parts[{k}].", texture_files)))
    surface = _read_surface(root, meta_path, doc, "", texture_files)
    shapes = _read_blendshapes(root, meta_path, doc, {"": len(surface["vertices"]),
                                                      **{name: len(s["vertices"]) for name, s in part_surfaces}})
    parts = [Asset(**s, name=name, blendshapes=shapes.get(name)) for name, s in part_surfaces]
    face_triangles = None
    if "face_triangles" in doc:
        face_triangles = np.zeros(len(surface["triangles"]), dtype=bool)
        try:
            for start, stop in doc["face_triangles"]:
                if not 0 <= int(start) < int(stop) <= len(face_triangles):
                    raise ValueError(f"range [{start}, {stop}) outside [0, {len(face_triangles)}]")
                face_triangles[int(start):int(stop)] = True
        except (TypeError, ValueError) as exc:
            raise InputError(meta_path, "face_triangles", "[start, stop) triangle ranges", str(exc)) from None
    asset = Asset(**surface, name=str(doc.get("name", "face")), metadata=doc.get("metadata", {}) or {},
                  parts=parts, face_triangles=face_triangles, blendshapes=shapes.get(""))
    asset.validate(str(root))
    return asset


def _read_surface(root: Path, meta_path: Path, doc: dict[str, Any], where: str,
                  texture_files: TextureFiles | None) -> dict[str, Any]:
    """Mesh, maps and constants of one record (the asset or one of its parts) as Asset fields;
    the map files are offered to ``texture_files``."""
    mesh_file = root / str(doc.get("mesh", _MESH_FILE))
    vertices, triangles, uv, uv_triangles = read_obj(mesh_file)
    if uv is None:
        raise InputError(mesh_file, "vt", "texture coordinates (f v/vt)", "none")
    maps = {}
    records = doc.get("maps", {})
    if not isinstance(records, dict):
        raise InputError(meta_path, f"{where}maps", "an object of map records")
    for name, rec in records.items():
        field = f"{where}maps.{name}"
        if name not in MAP_CHANNELS:
            raise InputError(meta_path, field, f"one of {', '.join(MAP_NAMES)}", repr(name))
        try:
            file = root / str(rec["file"])
            encoding = {"bits": int(rec["bits"]), "scale": float(rec["scale"]), "offset": float(rec["offset"])}
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(meta_path, field, "file, bits, scale and offset", str(exc)) from None
        if encoding["bits"] not in (8, 16):
            raise InputError(meta_path, f"{field}.bits", "8 or 16", str(encoding["bits"]))
        for key in ("scale", "offset"):
            if not np.isfinite(encoding[key]):
                raise InputError(meta_path, f"{field}.{key}", "a finite number", repr(encoding[key]))
        if not file.is_file():
            raise InputError(file, field, "an image file", "no such file")
        image, data = read_png_file(file)
        expected_dtype = np.uint8 if encoding["bits"] == 8 else np.uint16
        if image.dtype != expected_dtype:
            raise InputError(file, field, f"a {encoding['bits']}-bit image", f"{image.dtype}")
        channels = MAP_CHANNELS[name]
        if (channels == 1 and image.ndim != 2) or (channels > 1 and (image.ndim != 3 or image.shape[2] != channels)):
            raise InputError(file, field, f"{channels} channel(s)", str(image.shape))
        if "shape" in rec and list(image.shape) != list(rec["shape"]):
            raise InputError(file, field, f"shape {rec['shape']} (as recorded)", str(list(image.shape)))
        maps[name] = decode_map(name, image, encoding)
        if texture_files is not None:
            texture_files.add_file(maps[name], image, data)
    constants = doc.get("constants", {}) or {}
    return {"vertices": vertices, "triangles": triangles, "uv": uv, "uv_triangles": uv_triangles,
            "maps": maps, "constants": constants}
