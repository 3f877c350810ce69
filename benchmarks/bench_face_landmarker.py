"""MediaPipe's face-mesh models against each other: landmark bias on the head-scan renders, speed,
and the factories that let ``bench_fit_scans.py`` fit with either (issue 48).

    python benchmarks/bench_face_landmarker.py bias [--scans james lee_perry_smith] [--json OUT.json]
    python benchmarks/bench_face_landmarker.py speed [--repeats 30] [--json OUT.json]
    python benchmarks/bench_face_landmarker.py table --bias BIAS.json --fits V1.json V2.json [--speed SPEED.json]

    python benchmarks/bench_fit_scans.py --scans james lee_perry_smith --json V1.json \\
        --fitter bench_face_landmarker:hybrid_v1_fitter
    python benchmarks/bench_fit_scans.py --scans james lee_perry_smith --json V2.json \\
        --fitter bench_face_landmarker:hybrid_v2_fitter

The models (:data:`facegeo.landmarks.mediapipe_mesh.MESH_MODELS`): ``v1``, the 192² 468-point
``face_landmark.tflite`` of the ``mediapipe`` 0.10.14 wheel, and ``v2``, the 256² 478-point
``face_landmarks_detector.tflite`` of the Face Landmarker bundle ``face_landmarker.task`` ("Face mesh
detection model v2"). Both run behind the same BlazeFace detection and ROI (one refinement pass).

``bias``: on every rendered view of the scans (:mod:`scan_renders`), the scan's 68 landmarks
(:mod:`head_scans`: james's are annotated by hand with the scan, lee_perry_smith's were found by
facegeo's hybrid detector, i.e. dlib's predictor, on a ray-cast of the colour map, so they are a
dlib reference rather than ground truth) are projected with the view's true camera and pose and
compared with the 68 iBUG points each mesh model gives (:func:`ibug68_from_mesh`) and, for
reference, with the hybrid detector's (dlib's) 68. Distances in % of the projected annotated
outer-eye-corner distance (36-45); medians per view over the inner face (17-67) points seen in
the view (a point counts as seen when the view's point map at its pixel lies within 6 mm of it:
far-side brow and eye corners at ±40° yaw are hidden), over the lip points (48-67: the 20 the
hybrid detector takes from MediaPipe) and over the jaw (0-16: outline vs surface points, seen or
not).

``speed``: the bundled photo; per face, BlazeFace + two mesh passes (``MediaPipeFaceMesh.__call__``),
one mesh inference alone, and the whole hybrid detection (rotation search, dlib, the mirror pass
for the spread); min / median of ``--repeats`` after a warm-up, on the threads LiteRT is given by
default (``os.cpu_count()``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from facegeo.landmarks.detectors import HybridDetector, MediaPipeDetector  # noqa: E402
from facegeo.landmarks.mediapipe_mesh import MESH_MODELS, MediaPipeFaceMesh, ibug68_from_mesh  # noqa: E402

MODELS = tuple(MESH_MODELS)
INNER = np.arange(17, 68)
LIPS = np.arange(48, 68)
JAW = np.arange(0, 17)
SEEN_MM = 6.0


def hybrid_detector(mesh_model: str) -> HybridDetector:
    """facegeo's hybrid detector (dlib's 68 + MediaPipe's lips and 468 dense points) with the
    face-mesh model ``mesh_model``."""
    return HybridDetector(mediapipe=MediaPipeDetector(MediaPipeFaceMesh(mesh_model=mesh_model)))


def _fitter(mesh_model: str, hybrid: bool = True):
    from bench_fit_scans import facegeo_fitter

    mesh = MediaPipeFaceMesh(mesh_model=mesh_model)
    detector = HybridDetector(mediapipe=MediaPipeDetector(mesh)) if hybrid else MediaPipeDetector(mesh)
    return facegeo_fitter(detector=detector)


def hybrid_v1_fitter():
    """``bench_fit_scans.py --fitter bench_face_landmarker:hybrid_v1_fitter``."""
    return _fitter("v1")


def hybrid_v2_fitter():
    """``bench_fit_scans.py --fitter bench_face_landmarker:hybrid_v2_fitter``."""
    return _fitter("v2")


def mediapipe_v1_fitter():
    """The ``mediapipe`` detector (the mesh's 68 + lips + dense points, no dlib) with v1."""
    return _fitter("v1", hybrid=False)


def mediapipe_v2_fitter():
    """The ``mediapipe`` detector with v2."""
    return _fitter("v2", hybrid=False)


# ----------------------------------------------------------------------------------- bias


def _seen(view, points_px: np.ndarray, points_mm: np.ndarray) -> np.ndarray:
    """(N,) bool: the view's point map (scan space, mm) at each projected point (corner-origin px)
    lies within SEEN_MM of the point (scan space, mm)."""
    surface = view.points
    height, width = surface.shape[:2]
    col = np.clip(np.floor(points_px[:, 0]).astype(int), 0, width - 1)
    row = np.clip(np.floor(points_px[:, 1]).astype(int), 0, height - 1)
    gap = np.linalg.norm(surface[row, col].astype(np.float64) - points_mm, axis=1)
    return np.isfinite(gap) & (gap < SEEN_MM)


def bias(scans: list[str]) -> list[dict]:
    """Per scan and view: the 68 points of each mesh model and of the hybrid detector against
    the projected scan landmarks (module docstring)."""
    from head_scans import load_scan
    from scan_renders import load_view, render_views, view_names

    from facegeo import project

    meshes = {name: MediaPipeFaceMesh(mesh_model=name) for name in MODELS}
    hybrid = hybrid_detector("v1")
    rows = []
    for scan_name in scans:
        render_views(scan_name)
        scan = load_scan(scan_name)
        for view_name in view_names():
            view = load_view(scan_name, view_name)
            image = view.image
            truth = np.asarray(project(scan.annotation, view.rotation, view.translation, view.camera), np.float64)
            iod = float(np.linalg.norm(truth[36] - truth[45]))
            seen = _seen(view, truth, np.asarray(scan.annotation, np.float64))
            row = {"scan": scan_name, "view": view_name, "iod_px": iod, "inner_seen": int(seen[INNER].sum()),
                   "detectors": {}}
            found = {}
            for name, mesher in meshes.items():
                faces = mesher(image)
                if faces:
                    found[name] = ibug68_from_mesh(faces[0].mesh).astype(np.float64) + 0.5  # corner origin
            found["dlib (hybrid)"] = hybrid.detect(image, str(view.image_path)).points[:68].astype(np.float64)
            for name, points in found.items():
                error = np.linalg.norm(points - truth, axis=1) / iod * 100.0
                inner = INNER[seen[INNER]]
                row["detectors"][name] = {
                    "inner_seen_median_pct": float(np.median(error[inner])),
                    "inner_median_pct": float(np.median(error[INNER])),
                    "lips_median_pct": float(np.median(error[LIPS])),
                    "jaw_median_pct": float(np.median(error[JAW])),
                    "per_point_pct": error.round(3).tolist(),
                }
            rows.append(row)
            summary = ", ".join(f"{k} {v['inner_seen_median_pct']:.2f}" for k, v in row["detectors"].items())
            print(f"{scan_name:16s} {view_name:9s} inner-face median % IOD: {summary}", file=sys.stderr)
    return rows


# ----------------------------------------------------------------------------------- speed


def _times(call, repeats: int) -> dict:
    call()
    seconds = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        seconds.append(time.perf_counter() - t0)
    return {"min_ms": 1e3 * min(seconds), "median_ms": 1e3 * float(np.median(seconds)), "repeats": repeats}


def speed(repeats: int) -> dict:
    """Per model: ms per face for the mesh alone, BlazeFace + two passes, the hybrid detection."""
    from PIL import Image

    from facegeo.assets import asset_path

    image = np.asarray(Image.open(asset_path("photos/astronaut.png")).convert("RGB"))
    out = {}
    for name in MODELS:
        mesher = MediaPipeFaceMesh(mesh_model=name)
        face = mesher(image)[0]
        centre, side, angle = face.roi[:2].astype(np.float64), float(face.roi[2]), float(face.roi[3])
        detector = hybrid_detector(name)
        out[name] = {
            "mesh_inference": _times(lambda: mesher.mesh_in_roi(image, centre, side, angle), repeats),
            "blazeface_and_two_mesh_passes": _times(lambda: mesher(image), repeats),
            "hybrid_detect": _times(lambda: detector.detect(image), max(5, repeats // 3)),
            "file_bytes": Path(mesher.mesh_path or mesher._asset(mesher.mesh_spec.asset)).stat().st_size,
        }
        print(f"{name}: {json.dumps(out[name])}", file=sys.stderr)
    return out


# ----------------------------------------------------------------------------------- table


def table(bias_rows: list[dict], fits: dict[str, list[dict]], timing: dict | None) -> str:
    """Markdown: per scan and view, ratio to the mean shape (fit) and landmark bias, both models."""
    ratio = {(res["scan"], view, model): row["ratio"]
             for model, results in fits.items() for res in results for view, row in res["modes"]["default"].items()}
    lines = []
    for scan in dict.fromkeys(r["scan"] for r in bias_rows):
        rows = [r for r in bias_rows if r["scan"] == scan]
        lines += [f"**{scan}** (fit / mean shape: mean distance ratio, default camera; bias: median distance of the "
                  "68 points to the projected scan landmarks, % of the inter-ocular distance, inner face points seen "
                  "/ lips 48-67 / jaw 0-16)", "",
                  "| view | ratio v1 | ratio v2 | inner v1 | inner v2 | lips v1 | lips v2 | jaw v1 | jaw v2 | inner dlib |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            d = r["detectors"]

            def g(model: str, key: str) -> str:
                return f"{d[model][key]:.2f}" if model in d else "–"

            def q(model: str) -> str:
                value = ratio.get((scan, r["view"], model))
                return "–" if value is None else f"{value:.3f}"

            lines.append(f"| {r['view']} | {q('v1')} | {q('v2')} | {g('v1', 'inner_seen_median_pct')} | "
                         f"{g('v2', 'inner_seen_median_pct')} | {g('v1', 'lips_median_pct')} | {g('v2', 'lips_median_pct')} | "
                         f"{g('v1', 'jaw_median_pct')} | {g('v2', 'jaw_median_pct')} | "
                         f"{g('dlib (hybrid)', 'inner_seen_median_pct')} |")

        def med(model: str, key: str) -> str:
            values = [r["detectors"][model][key] for r in rows if model in r["detectors"]]
            return f"{np.median(values):.2f}" if values else "–"

        def medr(model: str) -> str:
            values = [v for (s, _, m), v in ratio.items() if s == scan and m == model]
            return f"{np.median(values):.3f}" if values else "–"

        lines.append(f"| **median** | {medr('v1')} | {medr('v2')} | {med('v1', 'inner_seen_median_pct')} | "
                     f"{med('v2', 'inner_seen_median_pct')} | {med('v1', 'lips_median_pct')} | {med('v2', 'lips_median_pct')} | "
                     f"{med('v1', 'jaw_median_pct')} | {med('v2', 'jaw_median_pct')} | "
                     f"{med('dlib (hybrid)', 'inner_seen_median_pct')} |")
        lines.append("")
    if timing:
        lines += ["| model | mesh inference ms (min / median) | BlazeFace + 2 mesh passes ms | hybrid detection ms | file bytes |",
                  "|---|---|---|---|---|"]
        for name, t in timing.items():
            cells = [f"{t[k]['min_ms']:.1f} / {t[k]['median_ms']:.1f}"
                     for k in ("mesh_inference", "blazeface_and_two_mesh_passes", "hybrid_detect")]
            lines.append(f"| {name} | " + " | ".join(cells) + f" | {t['file_bytes']} |")
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    b = sub.add_parser("bias", help="landmark bias on the scan renders")
    b.add_argument("--scans", nargs="+", default=["james", "lee_perry_smith"])
    b.add_argument("--json", type=Path)
    s = sub.add_parser("speed", help="time per face")
    s.add_argument("--repeats", type=int, default=30)
    s.add_argument("--json", type=Path)
    t = sub.add_parser("table", help="markdown from the JSON files")
    t.add_argument("--bias", type=Path, required=True)
    t.add_argument("--fits", type=Path, nargs=2, metavar=("V1_JSON", "V2_JSON"), required=True,
                   help="bench_fit_scans.py --json outputs with the v1 and v2 fitters")
    t.add_argument("--speed", type=Path)
    args = parser.parse_args()
    if args.command == "table":
        fits = {m: json.loads(p.read_text()) for m, p in zip(("v1", "v2"), args.fits)}
        timing = json.loads(args.speed.read_text()) if args.speed else None
        print(table(json.loads(args.bias.read_text()), fits, timing))
        return
    result = bias(args.scans) if args.command == "bias" else speed(args.repeats)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1))
    else:
        print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
