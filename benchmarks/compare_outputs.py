"""Compare two ``facegeo reconstruct`` output folders file by file: do they hold the same results?

    python benchmarks/compare_outputs.py BASELINE_FOLDER NEW_FOLDER

What "the same" means per kind of file (bytes may differ where only the encoding does):

* PNG: the decoded pixels are identical (shape, dtype, every value);
* OBJ and other text: identical text;
* JSON: identical after dropping every ``timings``/``timings_s`` entry (run times differ);
* ``.npz``: the same arrays;
* ``.glb``: the same JSON chunk once the buffer offsets and lengths are dropped, every accessor's
  data identical (dense and sparse) and every image's pixels identical;
* ``.usdz``: the same member files; the USD layer flattened to text identical, every PNG member's
  pixels identical.

Prints one line per file and exits with status 1 when any differs. Pixel comparisons decode with
OpenCV (:func:`facegeo.image_files.read_png_file` semantics).
"""

from __future__ import annotations

import argparse
import io
import json
import struct
import sys
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["compare_folders", "same_file"]


def _pixels(data: bytes) -> np.ndarray:
    import cv2

    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError("not a readable image")
    return image


def _same_pixels(a: bytes, b: bytes) -> bool:
    x, y = _pixels(a), _pixels(b)
    return x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y)


def _without_timings(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _without_timings(v) for k, v in value.items() if k not in ("timings", "timings_s")}
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


def _glb_chunks(data: bytes) -> tuple[dict[str, Any], bytes]:
    """(JSON chunk, BIN chunk) of a .glb file."""
    magic, _, _ = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF", "not a glb"
    pos, doc, blob = 12, None, b""
    while pos < len(data):
        length, kind = struct.unpack_from("<I4s", data, pos)
        chunk = data[pos + 8:pos + 8 + length]
        if kind == b"JSON":
            doc = json.loads(chunk)
        elif kind == b"BIN\0":
            blob = chunk
        pos += 8 + length
    assert doc is not None, "no JSON chunk"
    return doc, blob


def _same_glb(a: bytes, b: bytes) -> str | None:
    """None when the two glb files hold the same scene, else what differs."""
    (da, ba), (db, bb) = _glb_chunks(a), _glb_chunks(b)

    def view(doc: dict[str, Any], blob: bytes, index: int, offset: int = 0, length: int | None = None) -> bytes:
        v = doc["bufferViews"][index]
        start = v.get("byteOffset", 0) + offset
        return blob[start:start + (v["byteLength"] - offset if length is None else length)]

    def skeleton(doc: dict[str, Any]) -> dict[str, Any]:
        doc = json.loads(json.dumps(doc))
        for v in doc.get("bufferViews", []):
            v.pop("byteOffset", None)
            v.pop("byteLength", None)
        for buffer in doc.get("buffers", []):
            buffer.pop("byteLength", None)
        return doc

    if skeleton(da) != skeleton(db):
        return "JSON differs"
    for k, (xa, xb) in enumerate(zip(da.get("accessors", []), db.get("accessors", []))):
        if "bufferView" in xa and view(da, ba, xa["bufferView"], xa.get("byteOffset", 0)) != view(db, bb, xb["bufferView"], xb.get("byteOffset", 0)):
            return f"accessor {k} data differs"
        if "sparse" in xa:
            for part in ("indices", "values"):
                pa, pb = xa["sparse"][part], xb["sparse"][part]
                if view(da, ba, pa["bufferView"], pa.get("byteOffset", 0)) != view(db, bb, pb["bufferView"], pb.get("byteOffset", 0)):
                    return f"accessor {k} sparse {part} differ"
    for k, (ia, ib) in enumerate(zip(da.get("images", []), db.get("images", []))):
        if not _same_pixels(view(da, ba, ia["bufferView"]), view(db, bb, ib["bufferView"])):
            return f"image {k} ({ia.get('name')}) pixels differ"
    return None


def _flattened_usd(data: bytes, name: str) -> str:
    from pxr import Usd

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / name
        path.write_bytes(data)
        return Usd.Stage.Open(str(path)).Flatten().ExportToString()


def _same_usdz(a: bytes, b: bytes) -> str | None:
    """None when the two usdz packages hold the same layer and textures, else what differs."""
    za, zb = zipfile.ZipFile(io.BytesIO(a)), zipfile.ZipFile(io.BytesIO(b))
    names = za.namelist()
    if names != zb.namelist():
        return f"members differ: {names} vs {zb.namelist()}"
    for name in names:
        ma, mb = za.read(name), zb.read(name)
        if ma == mb:
            continue
        if name.lower().endswith(".png"):
            if not _same_pixels(ma, mb):
                return f"{name}: pixels differ"
        elif name.lower().endswith((".usdc", ".usda", ".usd")):
            if _flattened_usd(ma, Path(name).name) != _flattened_usd(mb, Path(name).name):
                return f"{name}: layer differs"
        else:
            return f"{name}: bytes differ"
    return None


def same_file(a: Path, b: Path) -> tuple[bool, str]:
    """``(same, how)``: whether files ``a`` and ``b`` hold the same results, and how that was
    decided (or what differs)."""
    x, y = a.read_bytes(), b.read_bytes()
    if x == y:
        return True, "identical bytes"
    suffix = a.suffix.lower()
    if suffix == ".png":
        return (True, "same pixels") if _same_pixels(x, y) else (False, "pixels differ")
    if suffix == ".json":
        same = _without_timings(json.loads(x)) == _without_timings(json.loads(y))
        return (True, "same apart from timings") if same else (False, "JSON differs")
    if suffix == ".npz":
        with np.load(a) as p, np.load(b) as q:
            same = sorted(p.files) == sorted(q.files) and all(np.array_equal(p[k], q[k]) for k in p.files)
        return (True, "same arrays") if same else (False, "arrays differ")
    if suffix == ".glb":
        problem = _same_glb(x, y)
        return (True, "same scene, accessors and image pixels") if problem is None else (False, problem)
    if suffix == ".usdz":
        problem = _same_usdz(x, y)
        return (True, "same layer and texture pixels") if problem is None else (False, problem)
    return False, "bytes differ"


def compare_folders(baseline: Path, new: Path) -> list[tuple[str, bool, str]]:
    """``(relative path, same, how)`` for every file of either folder."""
    files = sorted({p.relative_to(root).as_posix() for root in (baseline, new) for p in root.rglob("*") if p.is_file()})
    rows = []
    for rel in files:
        a, b = baseline / rel, new / rel
        if not a.is_file() or not b.is_file():
            rows.append((rel, False, f"only in {'new' if b.is_file() else 'baseline'}"))
            continue
        rows.append((rel, *same_file(a, b)))
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("baseline", type=Path)
    parser.add_argument("new", type=Path)
    args = parser.parse_args()
    rows = compare_folders(args.baseline, args.new)
    for rel, same, how in rows:
        print(f"{'same' if same else 'DIFFERS'}  {rel}: {how}")
    differing = sum(not same for _, same, _ in rows)
    print(f"{len(rows) - differing} of {len(rows)} files the same")
    return 1 if differing else 0


if __name__ == "__main__":
    sys.exit(main())
