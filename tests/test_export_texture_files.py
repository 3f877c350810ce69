"""Texture files made once per export (export.textures.TextureFiles) and PNG files embedded as
they are (image_files.plain_png, read_png_file)."""

from __future__ import annotations

import hashlib
import struct
import threading
import zipfile
import zlib
from collections import Counter

import numpy as np
import pytest

import facegeo.export.textures as textures_module
from facegeo.export.asset_io import load_asset, save_asset, write_asset_files
from facegeo.export.textures import TextureFiles, encode_map
from facegeo.export.writers import export_scenes
from facegeo.image_files import plain_png, png_bytes, read_png, read_png_file
from test_export_support import ict_asset, synthetic_maps
from test_export_asset_io import _run_cli


def _glb_images(path) -> dict[str, bytes]:
    """The embedded image files of a .glb by image name."""
    import pygltflib as gl

    doc = gl.GLTF2().load_binary(str(path))
    blob = doc.binary_blob()
    out = {}
    for image in doc.images:
        view = doc.bufferViews[image.bufferView]
        out[image.name] = blob[view.byteOffset:view.byteOffset + view.byteLength]
    return out


def _usdz_images(path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as package:
        return {name.rsplit("/", 1)[-1]: package.read(name) for name in package.namelist() if name.endswith(".png")}


@pytest.fixture
def counted(monkeypatch):
    """Every PNG encoding TextureFiles makes, counted by (shape, dtype, pixels)."""
    counts: Counter = Counter()

    def counting(image: np.ndarray) -> bytes:
        counts[(image.shape, image.dtype.str, hashlib.sha1(np.ascontiguousarray(image)).hexdigest())] += 1
        return png_bytes(image)

    monkeypatch.setattr(textures_module, "png_bytes", counting)
    return counts


def test_each_map_encoded_once_for_the_folder_and_both_scenes(tmp_path, counted):
    asset = ict_asset(size=32)
    files = TextureFiles()
    folder = tmp_path / "asset"
    folder.mkdir()
    write_asset_files(asset, folder, texture_files=files)
    export_scenes(asset, [(tmp_path / "face.usdz", None), (tmp_path / "face.glb", None)], maps=["albedo", "normal", "roughness", "specular"],
                  texture_files=files)
    # the folder's 5 maps (albedo 8-bit, the others 16-bit) and the scenes' 8-bit normal and roughness
    assert files.encoded == 7 == sum(counted.values()) == len(counted)
    albedo = (folder / "albedo.png").read_bytes()
    assert _glb_images(tmp_path / "face.glb")["albedo"] == albedo == _usdz_images(tmp_path / "face.usdz")["albedo.png"]
    assert _glb_images(tmp_path / "face.glb")["normal"] == _usdz_images(tmp_path / "face.usdz")["normal.png"]


def test_shared_files_are_what_each_writer_makes_alone(tmp_path):
    """The scenes written with one TextureFiles are byte for byte those written without."""
    asset = ict_asset(size=32)
    export_scenes(asset, [(tmp_path / "shared.glb", None)], texture_files=TextureFiles())
    export_scenes(asset, [(tmp_path / "alone.glb", None)])
    assert (tmp_path / "shared.glb").read_bytes() == (tmp_path / "alone.glb").read_bytes()
    assert _usdz_images(export_scenes(asset, [(tmp_path / "a.usdz", None)], texture_files=TextureFiles())[0]) == \
        _usdz_images(export_scenes(asset, [(tmp_path / "b.usdz", None)])[0])


def test_threads_asking_for_one_map_wait_for_one_encoding(counted):
    files = TextureFiles()
    albedo = synthetic_maps(64)["albedo"]
    start = threading.Barrier(4)
    results = []

    def ask() -> None:
        start.wait()
        results.append(files.map_png("albedo", albedo, 8))

    threads = [threading.Thread(target=ask) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert files.encoded == 1 == sum(counted.values())
    assert len(results) == 4 and all(r == results[0] for r in results)
    assert results[0][0] == png_bytes(encode_map("albedo", albedo, 8)[0])


def test_a_failed_encoding_is_raised_to_every_caller_and_not_kept(monkeypatch):
    files = TextureFiles()
    albedo = synthetic_maps(8)["albedo"]
    monkeypatch.setattr(textures_module, "png_bytes", lambda image: (_ for _ in ()).throw(OSError("disk on fire")))
    with pytest.raises(OSError, match="disk on fire"):
        files.map_png("albedo", albedo, 8)
    monkeypatch.setattr(textures_module, "png_bytes", png_bytes)
    assert files.map_png("albedo", albedo, 8)[0] == png_bytes(encode_map("albedo", albedo, 8)[0])


def _with_chunk(data: bytes, kind: bytes, body: bytes) -> bytes:
    """``data`` with one more chunk right after IHDR."""
    end_of_ihdr = 8 + 12 + struct.unpack_from(">I", data, 8)[0]
    chunk = struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    return data[:end_of_ihdr] + chunk + data[end_of_ihdr:]


def test_plain_png():
    data = png_bytes(np.zeros((4, 4, 3), np.uint8))
    assert plain_png(data)
    assert plain_png(_with_chunk(data, b"tEXt", b"Comment\0hello"))
    assert not plain_png(_with_chunk(data, b"gAMA", struct.pack(">I", 45455)))
    assert not plain_png(_with_chunk(data, b"sRGB", b"\0"))
    assert not plain_png(data[:-12])  # no IEND
    assert not plain_png(b"GIF89a" + data[6:])


def test_read_png_file(tmp_path):
    image = (np.arange(48, dtype=np.uint16).reshape(4, 4, 3) * 1000)
    (tmp_path / "a.png").write_bytes(png_bytes(image))
    pixels, data = read_png_file(tmp_path / "a.png")
    assert np.array_equal(pixels, image) and np.array_equal(read_png(tmp_path / "a.png"), image)
    assert data == (tmp_path / "a.png").read_bytes()
    from facegeo.errors import InputError

    with pytest.raises(InputError, match="readable PNG"):
        read_png_file(tmp_path / "missing.png")
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match="readable PNG"):
        read_png(tmp_path / "bad.png")


def test_export_command_embeds_the_folders_files_as_they_are(tmp_path, counted):
    folder = save_asset(ict_asset(size=32), tmp_path / "asset")
    counted.clear()
    _run_cli(["export", str(folder), "-o", str(tmp_path / "out" / "face"), "--format", "usdz,glb"])
    albedo = (folder / "albedo.png").read_bytes()
    assert _glb_images(tmp_path / "out" / "face.glb")["albedo"] == albedo
    assert _usdz_images(tmp_path / "out" / "face.usdz")["albedo.png"] == albedo
    # the 16-bit normal and roughness files are not what the scenes carry (8-bit): encoded, once each
    assert sorted(key[1] for key in counted) == ["|u1", "|u1"] and set(counted.values()) == {1}
    # a file that says more than its pixels (here a gamma) is not embedded; its pixels are
    (folder / "albedo.png").write_bytes(_with_chunk(albedo, b"gAMA", struct.pack(">I", 45455)))
    _run_cli(["export", str(folder), "-o", str(tmp_path / "again.glb")])
    embedded = _glb_images(tmp_path / "again.glb")["albedo"]
    assert embedded != (folder / "albedo.png").read_bytes() and plain_png(embedded)
    assert np.array_equal(_decoded(embedded), read_png(folder / "albedo.png"))


def _decoded(data: bytes) -> np.ndarray:
    import cv2

    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)[:, :, ::-1]


def test_loaded_assets_keep_their_pixels(tmp_path):
    """An asset loaded with texture_files decodes to the same maps as one loaded without."""
    folder = save_asset(ict_asset(size=16), tmp_path / "asset")
    plain, offered = load_asset(folder), load_asset(folder, texture_files=TextureFiles())
    assert plain.maps.keys() == offered.maps.keys()
    assert all(np.array_equal(plain.maps[k], offered.maps[k]) for k in plain.maps)


@pytest.mark.parametrize("odd", [None, 0, 1, 63, 64, 511 * 512 + 7])
def test_a_map_is_a_value_only_where_every_texel_is_within_its_tolerance(odd):
    """``material_inputs``' uniformity check judges a sample first: a single texel off the
    sample's grid (or on it) still makes the map a texture; a uniform one becomes its value."""
    from dataclasses import replace

    from facegeo.export.textures import material_inputs

    asset = ict_asset()
    roughness = np.full((512, 512), 0.4, np.float32)
    if odd is not None:
        roughness.reshape(-1)[odd] = 0.41
    inputs = material_inputs(replace(asset, maps={**asset.maps, "roughness": roughness},
                                     constants={k: v for k, v in asset.constants.items() if k != "roughness"}), ["roughness"])
    assert inputs["roughness"].is_texture == (odd is not None)
    if odd is None:
        assert inputs["roughness"].value == pytest.approx(0.4)
