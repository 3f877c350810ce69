"""Landmark-fit speed: ``fit_landmarks`` beside eos's ``fit_shape_and_pose`` on the same landmarks.

    EOS_PYTHON=/tmp/eosenv/bin/python EOS_SHARE=/tmp/eos_share/share \\
        python benchmarks/bench_fit_speed.py [--rounds 5]

Landmarks: the detected landmarks of the real photos (:func:`sample_photos`) and 10 real-like
validation faces (:mod:`fit_validation`). Per round, every case is fitted once by facegeo (88
points, 1 BLAS thread, the default), by facegeo with 2 BLAS threads, and by eos (its 68 iBUG
points, Surrey Face Model with expression blendshapes, its default 5 iterations; run by
``eos_timing.py`` in eos's own interpreter, model files loaded before timing); rounds alternate so
that machine load hits all alike. Times are CPU time of the fitting process (``process_time``):
on a shared, loaded machine wall time measures the neighbours. Reported per case: min and
median ms over the rounds and the ratio facegeo / eos of the medians. Without ``EOS_PYTHON`` the eos columns are left out.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fit_validation import CAMERA, make_faces  # noqa: E402
from sample_photos import sample_photos  # noqa: E402

import facegeo.fitting.landmark_fit as fitting  # noqa: E402
from facegeo.landmarks.scheme import IBUG68  # noqa: E402
from facegeo import Camera, detect_landmarks, load_model, load_photo  # noqa: E402


def cases(model) -> list[tuple[str, np.ndarray, Camera]]:
    out = []
    for path in sample_photos():
        photo = load_photo(path)
        h, w = photo.image.shape[:2]
        out.append((path.stem, detect_landmarks(photo.image), Camera.for_image(w, h)))
    for i, face in enumerate(make_faces(model, 10, seed=3)):
        out.append((f"real-like {i} ({face.expression}, yaw {face.yaw:.0f})", face.landmarks, CAMERA))
    return out


def time_ours(model, items, threads: int) -> list[float]:
    fitting.LANDMARK_FIT_THREADS = threads
    seconds = []
    for _, points, camera in items:
        t0 = time.process_time()
        fitting.fit_landmarks(model, points, camera)
        seconds.append(time.process_time() - t0)
    fitting.LANDMARK_FIT_THREADS = 1
    return seconds


def time_eos(items) -> list[float] | None:
    python = os.environ.get("EOS_PYTHON")
    if not python:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        spec = Path(tmp) / "landmarks.json"
        spec.write_text(json.dumps([{"points": p[IBUG68].tolist(), "width": c.width, "height": c.height} for _, p, c in items]))
        script = Path(__file__).resolve().parent / "eos_timing.py"
        out = subprocess.run([python, str(script), str(spec)], capture_output=True, text=True, check=True).stdout
    return json.loads(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    torch.set_num_threads(2)
    model = load_model()
    items = cases(model)
    time_ours(model, items[:1], 1)  # warm-up (first-call costs)
    runs: dict[str, list[list[float]]] = {"ours1": [], "ours2": [], "eos": []}
    for _ in range(args.rounds):
        runs["ours1"].append(time_ours(model, items, 1))
        runs["ours2"].append(time_ours(model, items, 2))
        eos = time_eos(items)
        if eos is not None:
            runs["eos"].append(eos)
    print(f"load average {os.getloadavg()[0]:.1f}; {args.rounds} rounds; CPU ms per fit (min / median)\n")
    print("| landmarks | facegeo, 1 thread | facegeo, 2 threads | eos | facegeo / eos (medians) |\n|---|---|---|---|---|")
    ratios = []
    for i, (name, _, _) in enumerate(items):
        cells = []
        for key in ("ours1", "ours2", "eos"):
            if runs[key]:
                values = 1000 * np.array([r[i] for r in runs[key]])
                cells.append(f"{values.min():.0f} / {np.median(values):.0f}")
            else:
                cells.append("–")
        ratio = "–"
        if runs["eos"]:
            r = np.median([x[i] for x in runs["ours1"]]) / np.median([x[i] for x in runs["eos"]])
            ratios.append(r)
            ratio = f"{r:.2f}"
        print(f"| {name} | {cells[0]} | {cells[1]} | {cells[2]} | {ratio} |")
    if ratios:
        print(f"\nfacegeo / eos: median {np.median(ratios):.2f}, max {np.max(ratios):.2f}")


if __name__ == "__main__":
    main()
