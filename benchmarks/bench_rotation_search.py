"""Cost of the detectors' rotation search (BlazeFace on four quarter turns of the photo).

For each detector: the time of ``detect`` (search included) and of the search alone
(:func:`facegeo.landmarks.detectors.upright_quarter_turns`), on the bundled photo (512²) and on
a copy upscaled to 2048² (the default ``--max-side``); ``--repeats`` runs each, min and median.

    python benchmarks/bench_rotation_search.py --repeats 7
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import cv2
import torch

from facegeo.assets import asset_path
from facegeo.landmarks.detectors import get_detector, upright_quarter_turns
from facegeo.photo import load_photo


def timed(fn, repeats: int) -> tuple[float, float]:
    """(min, median) seconds of ``repeats`` calls after one warm-up call."""
    fn()
    runs = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - t)
    return min(runs), statistics.median(runs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    torch.set_num_threads(1)
    photo = load_photo(asset_path("photos/astronaut.png")).image
    images = {"512²": photo, "2048²": cv2.resize(photo, (2048, 2048), interpolation=cv2.INTER_CUBIC)}
    print(f"load average {os.getloadavg()[0]:.2f}, {args.repeats} repeats, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}")
    print("| detector | photo | detect min / median ms | search min / median ms | search share (median) |")
    print("|---|---|---|---|---|")
    for name in ("mediapipe", "hybrid", "dlib"):
        detector = get_detector(name)
        for label, image in images.items():
            d_min, d_med = timed(lambda: detector.detect(image), args.repeats)
            s_min, s_med = timed(lambda: upright_quarter_turns(image), args.repeats)
            print(f"| {name} | {label} | {1e3 * d_min:.0f} / {1e3 * d_med:.0f} | {1e3 * s_min:.0f} / {1e3 * s_med:.0f} | "
                  f"{100 * s_med / d_med:.0f} % |", flush=True)


if __name__ == "__main__":
    main()
