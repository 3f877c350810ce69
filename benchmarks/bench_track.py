"""The per-frame solve of ``facegeo track``: error against run time for its knob, the
Levenberg–Marquardt iterations a frame (:data:`facegeo.tracking.TRACK_STAGE`).

    python benchmarks/bench_track.py CLIP [--iterations 1 2 4 8 16] [--reference 64] [--repeat 3]

The clip's frames are observed once (the hybrid detector's landmarks and dense points), the
identity and camera fitted as ``facegeo track`` does, then every frame with a face is solved
warm-started from the frame before with each iteration count. Error: against the solve with
``--reference`` iterations, per frame, the largest expression-weight difference and the head
rotation's angle difference (degrees), median and max over the frames; time: seconds per frame
(min and median of ``--repeat`` passes).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time
from pathlib import Path

import numpy as np

from facegeo import load_model
from facegeo.tracking import TRACK_STAGE, clip_identity, observe_frames, track_observed
from facegeo.video import open_video


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cos = (np.trace(np.asarray(a, np.float64).T @ np.asarray(b, np.float64)) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("clip", type=Path)
    parser.add_argument("--iterations", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    parser.add_argument("--reference", type=int, default=64)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    model = load_model()
    _, frames = open_video(args.clip)
    observed, size = observe_frames(frames, model, source=str(args.clip))
    shared = clip_identity(model, observed, size, source=str(args.clip))
    count = sum(f.observation is not None for f in observed)

    def run(iterations: int) -> tuple[list, float]:
        start = time.perf_counter()
        tracked = track_observed(model, observed, shared, dataclasses.replace(TRACK_STAGE, iterations=iterations))
        return [f for f in tracked if f.found], (time.perf_counter() - start) / max(count, 1)

    reference, _ = run(args.reference)
    print(f"clip {args.clip}: {len(observed)} frames, {count} with a face; reference {args.reference} iterations a frame\n")
    print("| iterations a frame | s a frame (min / median) | max weight difference (median / max) | rotation difference ° (median / max) |")
    print("|---:|---:|---:|---:|")
    for iterations in args.iterations:
        times, result = [], []
        for _ in range(args.repeat):
            result, seconds = run(iterations)
            times.append(seconds)
        weights = [float(np.abs(r.delta - q.delta).max()) for r, q in zip(result, reference)]
        angles = [_angle_deg(r.rotation, q.rotation) for r, q in zip(result, reference)]
        print(f"| {iterations} | {min(times):.4f} / {statistics.median(times):.4f} | {np.median(weights):.4f} / {max(weights):.4f} | "
              f"{np.median(angles):.3f} / {max(angles):.3f} |")


if __name__ == "__main__":
    main()
