"""Issues 29 and 26: the texture stages' run time against a baseline checkout, and their output.

The texture path of ``facegeo reconstruct`` (``facegeo.pipeline.reconstruct_with_fit`` after the
fit: stage ``unwrap`` = UV raster, geometry maps, unwrap and texture context; then ``inpaint``,
``homogenise``, ``materials``) is timed in this checkout and in a baseline checkout
(``--baseline``, e.g. a checkout of main) on the same fits, alternated in one run:

1. The fits: the bundled photo and ``~/.cache/facegeo/samples/*.png`` are fitted once by this
   checkout (``facegeo.fit``, with ``facegeo.skin_mask.skin_mask`` as the CLI does) and pickled;
   photos the fit refuses are skipped. Both checkouts then get the same fit (the fitter passed to
   ``reconstruct_with_fit`` returns a copy of it; ``parts=False``).
2. **cold**: per repeat and checkout a fresh worker process (imports done before timing) runs the
   texture path once on the first photo: what one ``facegeo reconstruct`` pays, caches empty.
3. **warm**: one long-lived worker per checkout runs it on every photo, ``--repeats`` times (what
   ``facegeo batch`` pays per photo after its first).

Each worker imports ``facegeo`` and the sub-packages ``pyproject.toml`` maps from other folders
(``facegeo.texturing`` → ``texturing/``, ...) from its own checkout, whatever the installed
editable points at. Baseline and candidate alternate, the order swapped every repeat; stage times
are ``asset.metadata["timings_s"]``; the ratio candidate / baseline is taken per repeat (the
machine's load changes slowly) and reported as min and median, beside each side's min and median
seconds. Workers run with ``--threads`` threads (OMP/OpenBLAS/MKL environment, ``torch`` and
OpenCV).

Output: every map of every photo is compared between the checkouts bit for bit (the float32
arrays) and as the PNG the asset folder writes (``facegeo.export.textures.encode_map``, 8 bits,
displacement 16): the largest difference in PNG levels and the number of texels that differ.

    python benchmarks/bench_texture_stages.py --baseline /path/to/main-checkout
    python benchmarks/bench_texture_stages.py --baseline ../base --repeats 5 --cold 3 --threads 2
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import platform
import shlex
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("unwrap", "inpaint", "homogenise", "materials")
SAMPLES = Path.home() / ".cache" / "facegeo" / "samples"


# ------------------------------------------------------------------------------- the worker side
def import_checkout(root: Path) -> None:
    """Make ``import facegeo`` and the packages ``pyproject.toml`` maps to other folders
    (``[tool.setuptools] package-dir``) load from ``root``, ahead of any installed copy."""
    import importlib.abc
    import importlib.util
    import tomllib

    package_dir = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]

    class CheckoutFinder(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name not in package_dir:
                return None
            folder = root / package_dir[name]
            return importlib.util.spec_from_file_location(name, folder / "__init__.py", submodule_search_locations=[str(folder)])

    sys.meta_path.insert(0, CheckoutFinder())


def worker(root: Path, inputs: Path, threads: int) -> None:
    """Serve requests on stdin, one JSON line each: ``{"photo": i, "save": path or null}`` ->
    one JSON line ``{"timings": {stage: s}, "digests": {map: sha256}, "file": facegeo's path}``."""
    import_checkout(root)
    import copy

    import cv2
    import numpy as np
    import torch

    cv2.setNumThreads(threads)
    torch.set_num_threads(threads)
    import facegeo
    from facegeo import load_model
    from facegeo.pipeline import reconstruct_with_fit

    items = pickle.loads(inputs.read_bytes())
    model = load_model()
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        request = json.loads(line)
        item = items[request["photo"]]
        fit = copy.deepcopy(item["fit"])
        asset, _ = reconstruct_with_fit(item["photo_obj"], model, skin=item["skin"], parts=False,
                                        fitter=lambda *args, _fit=fit, **kwargs: _fit)
        if request.get("save"):
            np.savez(request["save"], **asset.maps)
        print(json.dumps({
            "timings": {k: asset.metadata["timings_s"][k] for k in STAGES},
            "digests": {k: hashlib.sha256(np.ascontiguousarray(v).tobytes()).hexdigest() for k, v in asset.maps.items()},
            "file": facegeo.__file__,
        }), flush=True)


# ------------------------------------------------------------------------------- the parent side
class Worker:
    """A worker process of one checkout."""

    def __init__(self, root: Path, inputs: Path, threads: int):
        env = dict(os.environ, OMP_NUM_THREADS=str(threads), OPENBLAS_NUM_THREADS=str(threads), MKL_NUM_THREADS=str(threads))
        env.pop("PYTHONPATH", None)
        self.proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker", str(root), str(inputs), str(threads)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=root)
        self._read()

    def _read(self) -> dict:
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"worker exited with {self.proc.wait()}")
        return json.loads(line)

    def run(self, photo: int, save: Path | None = None) -> dict:
        self.proc.stdin.write(json.dumps({"photo": photo, "save": None if save is None else str(save)}) + "\n")
        self.proc.stdin.flush()
        return self._read()

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait()


def prepare(photos: list[Path], out: Path) -> list[str]:
    """Fit ``photos`` with this checkout and pickle what the texture path needs; the names kept."""
    from facegeo import load_model
    from facegeo.errors import FacegeoError
    from facegeo.fitting import fit
    from facegeo.photo import load_photo
    from facegeo.skin_mask import skin_mask

    model = load_model()
    items, names = [], []
    for path in photos:
        photo = load_photo(path)
        skin = skin_mask(photo.image, source=str(path))
        try:
            result = fit(photo, model=model)
        except FacegeoError as exc:
            print(f"skipped {path.name}: {type(exc).__name__}", file=sys.stderr)
            continue
        items.append({"name": path.stem, "photo_obj": photo, "skin": skin, "fit": result})
        names.append(path.stem)
    out.write_bytes(pickle.dumps(items))
    return names


def compare_maps(a: Path, b: Path) -> dict[str, tuple[bool, int, int]]:
    """map -> (float32 bits identical, largest PNG-level difference, texels whose PNG differs)."""
    import numpy as np

    from facegeo.export.textures import encode_map

    x, y = np.load(a), np.load(b)
    out = {}
    for name in x.files:
        same = x[name].dtype == y[name].dtype and np.array_equal(x[name].view(np.uint8), y[name].view(np.uint8))
        pa, _ = encode_map(name, x[name])
        pb, _ = encode_map(name, y[name])
        diff = np.abs(pa.astype(np.int64) - pb.astype(np.int64))
        texels = int((diff.reshape(diff.shape[0], diff.shape[1], -1).max(axis=-1) > 0).sum())
        out[name] = (same, int(diff.max()), texels)
    return out


def summary(base: list[dict], cand: list[dict]) -> list[tuple[str, float, float, float, float, float, float]]:
    """Per stage and the sum: (name, base min, base median, cand min, cand median, ratio min, ratio median)."""
    rows = []
    for stage in (*STAGES, "total"):
        b, c = ([sum(r["timings"].values()) if stage == "total" else r["timings"][stage] for r in side] for side in (base, cand))
        ratios = [ci / bi for bi, ci in zip(b, c)]
        rows.append((stage, min(b), statistics.median(b), min(c), statistics.median(c), min(ratios), statistics.median(ratios)))
    return rows


def table(title: str, rows) -> str:
    lines = [f"**{title}**", "", "| stage | baseline min / median (s) | this min / median (s) | ratio min / median |", "|---|---:|---:|---:|"]
    for name, bmin, bmed, cmin, cmed, rmin, rmed in rows:
        label = "unwrap + inpaint + homogenise + materials" if name == "total" else name
        lines.append(f"| {label} | {bmin:.3f} / {bmed:.3f} | {cmin:.3f} / {cmed:.3f} | {rmin:.2f} / {rmed:.2f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", type=Path, required=True, help="a checkout of the code to compare against")
    parser.add_argument("--repeats", type=int, default=3, help="warm runs per photo and checkout")
    parser.add_argument("--cold", type=int, default=3, help="cold runs (fresh processes) per checkout, on the first photo")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--photos", type=Path, nargs="*", default=None,
                        help="default: assets/photos/astronaut.png and ~/.cache/facegeo/samples/*.png")
    args = parser.parse_args()
    photos = args.photos or [ROOT / "assets" / "photos" / "astronaut.png", *sorted(SAMPLES.glob("*.png"))]
    import_checkout(ROOT)  # this process fits the photos and encodes the maps with this checkout
    baseline = args.baseline.resolve()
    with tempfile.TemporaryDirectory(prefix="bench_texture_stages_") as tmp:
        tmp = Path(tmp)
        inputs = tmp / "inputs.pkl"
        names = prepare(photos, inputs)
        sides = {"baseline": baseline, "this": ROOT}
        cold: dict[str, list[dict]] = {"baseline": [], "this": []}
        for r in range(args.cold):
            for side in (("baseline", "this") if r % 2 == 0 else ("this", "baseline")):
                w = Worker(sides[side], inputs, args.threads)
                cold[side].append(w.run(0))
                w.close()
        workers = {side: Worker(root, inputs, args.threads) for side, root in sides.items()}
        warm: dict[str, list[dict]] = {"baseline": [], "this": []}
        maps: dict[str, dict[str, tuple[bool, int, int]]] = {}
        for r in range(args.repeats):
            for i, name in enumerate(names):
                order = ("baseline", "this") if r % 2 == 0 else ("this", "baseline")
                results = {}
                for side in order:
                    save = tmp / f"{side}_{i}.npz" if r == 0 else None
                    results[side] = workers[side].run(i, save)
                    warm[side].append(results[side])
                if r == 0:
                    maps[name] = compare_maps(tmp / f"baseline_{i}.npz", tmp / f"this_{i}.npz")
        files = {side: w.run(0)["file"] for side, w in workers.items()}
        for w in workers.values():
            w.close()
    command = "python benchmarks/bench_texture_stages.py " + shlex.join(sys.argv[1:])
    print(f"{command}\n{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, {args.threads} threads, "
          f"load average at the end {' '.join(f'{x:.2f}' for x in os.getloadavg())}; "
          f"facegeo from {files['baseline']} (baseline) and {files['this']} (this); photos: {', '.join(names)}\n")
    print(table(f"cold (a fresh process per run, {names[0]}, {args.cold} runs per side)", summary(cold["baseline"], cold["this"])))
    print()
    print(table(f"warm (one process per side, {len(names)} photos x {args.repeats} runs)", summary(warm["baseline"], warm["this"])))
    print("\n| photo | " + " | ".join(next(iter(maps.values()))) + " |")
    print("|---|" + "---|" * len(next(iter(maps.values()))))
    for name, per_map in maps.items():
        cells = ["identical" if same else f"{diff} levels, {texels} texels" for same, diff, texels in per_map.values()]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--worker":
        worker(Path(sys.argv[2]), Path(sys.argv[3]), int(sys.argv[4]))
    else:
        main()
