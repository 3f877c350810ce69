"""PNG encoding: time against bytes for OpenCV's zlib levels, strategies and row filters, on the
maps of a real ``facegeo reconstruct`` output (issue 29).

    facegeo reconstruct assets/photos/astronaut.png -o /tmp/face
    python benchmarks/bench_png.py /tmp/face [--repeats 5]

The images are the asset folder's maps as they are stored (albedo 8-bit RGB, normal 16-bit RGB,
roughness, specular and displacement 16-bit grey, at the run's map size; the eyeballs' albedo),
and, for the totals, every distinct image one ``reconstruct`` encodes into the asset folder, the
usdz and the glb (recorded from ``cv2.imencode`` while the folder is re-exported the way the job
writes it). Each setting encodes each image ``--repeats`` times, the settings interleaved; the
table gives the fastest time of each (the machine is shared: the minimum is the least disturbed
measure), the bytes, and the decode time of the totals' images. Every setting is lossless: the
decoded pixels are checked against the image.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np


def settings() -> list[tuple[str, list[int]]]:
    """(label, cv2.imencode parameters) of every setting measured."""
    import cv2

    c, s, f = cv2.IMWRITE_PNG_COMPRESSION, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_FILTER
    strategies = {"default": cv2.IMWRITE_PNG_STRATEGY_DEFAULT, "filtered": cv2.IMWRITE_PNG_STRATEGY_FILTERED,
                  "huffman": cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY, "rle": cv2.IMWRITE_PNG_STRATEGY_RLE,
                  "fixed": cv2.IMWRITE_PNG_STRATEGY_FIXED}
    filters = {"none": cv2.IMWRITE_PNG_FILTER_NONE, "sub": cv2.IMWRITE_PNG_FILTER_SUB, "up": cv2.IMWRITE_PNG_FILTER_UP,
               "avg": cv2.IMWRITE_PNG_FILTER_AVG, "paeth": cv2.IMWRITE_PNG_FILTER_PAETH, "fast": cv2.IMWRITE_PNG_FAST_FILTERS}
    out = [("OpenCV's defaults (no parameters)", [])]
    out += [(f"level {level}, default strategy", [c, level, s, strategies["default"]]) for level in range(10)]
    out += [(f"level {level}, filtered", [c, level, s, strategies["filtered"]]) for level in (1, 3, 6)]
    out += [(f"level 1, {name}", [c, 1, s, strategies[name]]) for name in ("huffman", "rle", "fixed")]
    out += [(f"level 1, default strategy, filter {name}", [c, 1, s, strategies["default"], f, value]) for name, value in filters.items()]
    out += [(f"level 1, rle, filter {name}", [c, 1, s, strategies["rle"], f, value]) for name, value in filters.items()]
    return out


def folder_maps(folder: Path) -> list[tuple[str, np.ndarray]]:
    """The asset folder's map images as stored (OpenCV's BGR order, as encoded)."""
    import cv2

    names = ["albedo", "normal", "roughness", "specular", "displacement"]
    files = [(name, folder / f"{name}.png") for name in names] + [("eyeballs albedo", folder / "parts" / "eyeballs_albedo.png")]
    return [(name, cv2.imread(str(path), cv2.IMREAD_UNCHANGED)) for name, path in files if path.is_file()]


def run_images(folder: Path) -> list[np.ndarray]:
    """Every distinct image (BGR, as given to ``cv2.imencode``) that writing this folder's asset
    the way ``facegeo reconstruct`` does encodes: the asset folder, skin mask and preview aside,
    then the usdz and the glb (the maps of ``DISPLACEMENT_BAKE_RULE`` at subdiv 0)."""
    import tempfile

    import cv2

    from facegeo.export.asset_io import load_asset, write_asset_files
    from facegeo.export.textures import TextureFiles
    from facegeo.export.writers import export_scenes

    asset = load_asset(folder)
    seen: dict[bytes, np.ndarray] = {}
    encode = cv2.imencode

    def recording(ext, image, params=()):
        import hashlib

        seen.setdefault(hashlib.sha1(np.ascontiguousarray(image)).digest() + str((image.shape, image.dtype)).encode(), image.copy())
        return encode(ext, image, params)

    cv2.imencode = recording
    try:
        with tempfile.TemporaryDirectory() as tmp:
            files = TextureFiles()
            write_asset_files(asset, tmp, texture_files=files)
            export_scenes(asset, [(Path(tmp) / "face.usdz", None), (Path(tmp) / "face.glb", None)],
                          maps=[m for m in asset.maps if m != "displacement"], texture_files=files)
    finally:
        cv2.imencode = encode
    return list(seen.values())


def measure(images: list[np.ndarray], table: list[tuple[str, list[int]]], repeats: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(fastest encode seconds, bytes, fastest decode seconds), each (settings, images)."""
    import cv2

    seconds = np.full((len(table), len(images)), np.inf)
    decode = np.full((len(table), len(images)), np.inf)
    sizes = np.zeros((len(table), len(images)), dtype=np.int64)
    for _ in range(repeats):
        for i, (_, params) in enumerate(table):
            for j, image in enumerate(images):
                t = time.perf_counter()
                ok, buf = cv2.imencode(".png", image, params)
                seconds[i, j] = min(seconds[i, j], time.perf_counter() - t)
                assert ok
                sizes[i, j] = len(buf)
                t = time.perf_counter()
                back = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
                decode[i, j] = min(decode[i, j], time.perf_counter() - t)
                assert back.dtype == image.dtype and np.array_equal(back, image), "lossy?"
    return seconds, sizes, decode


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="a facegeo reconstruct output folder")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    import cv2

    named = folder_maps(args.folder)
    everything = run_images(args.folder)
    table = settings()
    print(f"machine: {os.cpu_count()} CPUs, load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}; OpenCV {cv2.__version__}")
    print(f"maps of {args.folder}: " + ", ".join(f"{n} {'x'.join(map(str, im.shape))} {im.dtype}" for n, im in named))
    print(f"one reconstruct encodes {len(everything)} distinct images "
          f"({sum(im.nbytes for im in everything) / 1e6:.1f} MB of pixels)")
    seconds, sizes, _ = measure([im for _, im in named], table, args.repeats)
    run_seconds, run_sizes, run_decode = measure(everything, table, args.repeats)
    raw = sum(im.nbytes for im in everything)
    print(f"\nfastest of {args.repeats}; ms / MB per map; the run: every distinct image of one reconstruct "
          "(asset folder + usdz + glb), encode and decode ms, MB, and MB relative to the raw pixels")
    header = "| setting | " + " | ".join(n for n, _ in named) + " | run: encode ms | run: decode ms | run: MB | run: of raw |"
    print(header)
    print("|" + "---|" * (header.count("|") - 1))
    for i, (label, _) in enumerate(table):
        cells = [f"{seconds[i, j] * 1e3:.0f} / {sizes[i, j] / 1e6:.2f}" for j in range(len(named))]
        print(f"| {label} | " + " | ".join(cells) + f" | {run_seconds[i].sum() * 1e3:.0f} | {run_decode[i].sum() * 1e3:.0f} | "
              f"{run_sizes[i].sum() / 1e6:.2f} | {run_sizes[i].sum() / raw:.2f} |", flush=True)
    print(f"\nload average at the end {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
