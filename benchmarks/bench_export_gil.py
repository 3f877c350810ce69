"""How much each piece of the export stage holds the GIL (issue 29).

    python benchmarks/bench_export_stage.py make-fixture /tmp/fixture.pkl
    python benchmarks/bench_export_gil.py /tmp/fixture.pkl [REPEATS]

While a piece runs in a worker thread, the main thread sleeps 1 ms at a time and records how
late it wakes (it needs the GIL to go on). A piece that holds the GIL in one long C call delays
the main thread by that call's length; pure Python by about the 5 ms switch interval; a GIL-free
piece by scheduling noise only. A sleep and a pure-Python loop are the references.
"""
import pickle
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

photo, skin, asset, result = pickle.loads(Path(sys.argv[1]).read_bytes())
from facegeo.export.scene import scene_surfaces
from facegeo.export.textures import TextureFiles, encode_map
from facegeo.export.gltf import glb_bytes
from facegeo.export.usd import _write_layer, _prim_name
from facegeo.export.asset_io import write_asset_files
from facegeo.image_files import png_bytes
from facegeo.texturing.preview import relit_preview
carried = [m for m in asset.maps if m != "displacement"]
surfaces = scene_surfaces(asset, maps=carried, blendshapes="arkit")
files = TextureFiles()
tmp = Path(tempfile.mkdtemp())
img, _ = encode_map("normal", asset.maps["normal"], 16)
def usd_layer():
    d = Path(tempfile.mkdtemp(dir=tmp)); _write_layer(surfaces[0][1], [(_prim_name(n), c) for n, c in surfaces[1:]], d / "f.usdc", "face", "textures", 8, files)
    return d
d0 = usd_layer()
def usdz_package():
    from pxr import Sdf, UsdUtils
    UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(d0 / "f.usdc")), str(d0 / f"f{time.time_ns()}.usdz"))
def glb(): glb_bytes(asset, maps=carried, surfaces=surfaces, texture_files=files)   # textures already made: geometry + pygltflib
def python():
    x = 0
    for i in range(4_000_000): x += i
def sleep(): time.sleep(0.6)
def png16(): png_bytes(img)
def asset_folder(): write_asset_files(asset, Path(tempfile.mkdtemp(dir=tmp)), texture_files=TextureFiles())
def preview(): relit_preview(photo.image, asset, result)
def surf(): scene_surfaces(asset, maps=carried, blendshapes="arkit")
pieces = dict(sleep=sleep, python=python, png16=png16, usd_layer=usd_layer, usdz_package=usdz_package, glb=glb, surfaces=surf, asset_folder=asset_folder, preview=preview)
glb()
def probe(f):
    stop = threading.Event()
    th = threading.Thread(target=lambda: (f(), stop.set())); t0 = time.perf_counter(); th.start()
    lat = []
    while not stop.is_set():
        t = time.perf_counter(); time.sleep(0.001); lat.append(time.perf_counter() - t - 0.001)
    th.join()
    return time.perf_counter() - t0, lat
out = {k: ([], []) for k in pieces}
for rep in range(int(sys.argv[2]) if len(sys.argv) > 2 else 2):
    for k, f in pieces.items():
        d, lat = probe(f); out[k][0].append(d); out[k][1].extend(lat)
print("| piece | median s | main-thread wake-up delay: median ms | p99 ms | max ms | share of the piece's time the main thread was held up |")
print("|---|---|---|---|---|---|")
for k, (durs, lat) in out.items():
    lat = np.array(lat) * 1e3
    print(f"| {k} | {statistics.median(durs):.3f} | {np.median(lat):.2f} | {np.percentile(lat, 99):.1f} | {lat.max():.1f} | {lat.sum() / 1e3 / sum(durs):.2f} |")
