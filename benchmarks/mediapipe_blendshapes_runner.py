"""MediaPipe's Face Landmarker on a folder of frames: its 52 blendshape scores and the face's
transformation matrix per frame; run by bench_track_truth.py with the interpreter of a separate
virtual environment that has the ``mediapipe`` package (facegeo's own environment does not).

    /tmp/mpenv/bin/python benchmarks/mediapipe_blendshapes_runner.py --model face_landmarker.task \\
        --frames DIR --fps 30 --out OUT.json

The frames are ``DIR``'s PNG files in name order, frame k at k / fps seconds, given to the
landmarker in VIDEO mode (it follows the face from frame to frame as on a live clip), one face,
with ``output_face_blendshapes`` and ``output_facial_transformation_matrixes``. OUT.json:
``{"mediapipe": version, "frames": [{"file", "found", "blendshapes": {name: score}, "matrix":
4 × 4 row-major}], "seconds": wall time of the detection loop}``; a frame without a face has
``found`` false and nothing else. Imports only the standard library, NumPy and MediaPipe.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import mediapipe as mp
import numpy as np
from mediapipe.tasks.python import BaseOptions, vision


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, required=True, help="face_landmarker.task")
    parser.add_argument("--frames", type=Path, required=True, help="folder of PNG frames")
    parser.add_argument("--fps", type=float, required=True, help="the frames' rate (their timestamps)")
    parser.add_argument("--out", type=Path, required=True, help="the JSON written")
    args = parser.parse_args()
    files = sorted(args.frames.glob("*.png"))
    if not files:
        raise SystemExit(f"{args.frames}: no PNG frames")
    options = vision.FaceLandmarkerOptions(base_options=BaseOptions(model_asset_path=str(args.model)),
                                           running_mode=vision.RunningMode.VIDEO, num_faces=1,
                                           output_face_blendshapes=True, output_facial_transformation_matrixes=True)
    frames = []
    start = time.perf_counter()
    with vision.FaceLandmarker.create_from_options(options) as landmarker:
        for k, path in enumerate(files):
            image = mp.Image.create_from_file(str(path))
            result = landmarker.detect_for_video(image, int(round(1000 * k / args.fps)))
            if not result.face_blendshapes:
                frames.append({"file": path.name, "found": False})
                continue
            scores = {c.category_name: float(c.score) for c in result.face_blendshapes[0]}
            matrix = np.asarray(result.facial_transformation_matrixes[0], dtype=np.float64).reshape(4, 4)
            frames.append({"file": path.name, "found": True, "blendshapes": scores, "matrix": matrix.ravel().tolist()})
    seconds = time.perf_counter() - start
    args.out.write_text(json.dumps({"mediapipe": mp.__version__, "frames": frames, "seconds": seconds}))
    print(f"{len(frames)} frames, {sum(f['found'] for f in frames)} with a face, {seconds:.1f} s")


if __name__ == "__main__":
    main()
