"""One identity from a rendered head-turn clip of a real head scan: ``facegeo track`` as a user runs it.

    python benchmarks/bench_identity_clip.py [--scans james lee_perry_smith] [--step 4] [--samples 16]
                                             [--keyframes 5 ...] [--work DIR] [--json OUT.json]

For each head scan of :mod:`head_scans` a clip is rendered (once, Blender, cached beside the scan
benchmark's views, :func:`scan_renders.render_views`): the head turns from 0° to +40°, back to
0°, to −40° and back to 0° in steps of ``--step`` degrees of yaw, each frame one view (512 × 768,
a 50 mm lens at 600 mm, the even "soft" light of the identity benchmark). The frames are tracked
by ``facegeo track FRAMES -o OUT --no-asset`` in a fresh process (focal not given), and the
clip's identity α of ``track.json`` is measured NoW-style against the scan
(:mod:`scan_evaluation`, the scan's landmarks detected on the frontal render as in
``bench_fit_scans.py``), neutral (δ = 0), over the mean shape's error: issue 48's bar is ≤ 0.8 on
each head and better than the best single view (``bench_identity_views.py``'s five views, each
fitted alone, measured here again the same way).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fit_scans import scan_landmarks  # noqa: E402
from bench_identity_views import HEAD_TURN, _ratios  # noqa: E402
from head_scans import SCANS, load_scan  # noqa: E402
from scan_evaluation import Prediction, evaluate, prepare_scan  # noqa: E402
from scan_renders import ViewSpec, load_view, render_views  # noqa: E402

from facegeo import load_model  # noqa: E402


def turn_yaws(step: float) -> list[float]:
    """Yaw of each frame (degrees): 0 → +40 → 0 → −40 → 0 in steps of ``step``, no frame repeated
    at the turns."""
    up = list(np.arange(0.0, 40.0 + 1e-9, step))
    out = up + up[-2::-1] + [-y for y in up[1:]] + [-y for y in up[-2::-1]]
    return [float(y) for y in out]


def bench_scan(scan_name: str, model, step: float, samples: int, work: Path, keyframes: int) -> dict:
    """The clip rendered and tracked, and the errors of its identity, the mean shape's and the single views'."""
    from facegeo import fit

    yaws = turn_yaws(step)
    specs = tuple(ViewSpec(f"turn{k:03d}", yaw=y) for k, y in enumerate(yaws))
    t0 = time.perf_counter()
    render_views(scan_name, samples=samples, views=specs)
    render_s = time.perf_counter() - t0
    frames = work / scan_name / "frames"
    frames.mkdir(parents=True, exist_ok=True)
    for k, spec in enumerate(specs):
        link = frames / f"{k:05d}.png"
        if not link.exists():
            link.symlink_to(load_view(scan_name, spec.name).image_path)
    out = work / scan_name / f"track-{keyframes}"
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "facegeo.cli", "track", str(frames), "-o", str(out), "--no-asset", "--keyframes",
                           str(keyframes)],
                          capture_output=True, text=True)
    track_s = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"facegeo track failed: {done.stderr[-2000:]}")
    record = json.loads((out / "track.json").read_text())
    landmarks, _ = scan_landmarks(scan_name, "detected")
    scan = load_scan(scan_name)
    reference = prepare_scan(scan.vertices, scan.triangles, landmarks)
    mean = evaluate(Prediction(model.mean_shape, model.triangles, model.landmark_indices), reference)["mean"]
    zero = np.zeros(model.n_exp)
    clip = _ratios(model, reference, mean, np.asarray(record["alpha"], np.float64), zero)
    singles = {}
    for name in HEAD_TURN:
        result = fit(load_view(scan_name, name).image_path, model, photometric=False)
        singles[name] = _ratios(model, reference, mean, result.alpha, zero)["neutral_ratio"]
    keyframe_yaws = [yaws[k] for k in record["keyframes"]]
    return {"scan": scan_name, "frames": len(yaws), "keyframes_asked": keyframes, "step_deg": step, "samples": samples, "render_s": render_s,
            "track_s": track_s, "keyframes": record["keyframes"], "keyframe_yaws_deg": keyframe_yaws,
            "frames_with_face": record["frames_with_face"], "focal_px": record["camera"]["focal"], "mean_shape_mm": mean,
            "clip": clip, "single_neutral_ratio": singles}


def markdown(results: list[dict]) -> str:
    lines = ["| scan | frames (with a face) | keyframes | keyframes' yaw ° | clip identity mm | / mean shape | best single view / mean shape | bar (≤ 0.8 and < best view) |",
             "|---|---|---|---|---:|---:|---:|---|"]
    for r in results:
        best = min(r["single_neutral_ratio"].values())
        ratio = r["clip"]["neutral_ratio"]
        lines.append(f"| {r['scan']} | {r['frames']} ({r['frames_with_face']}) | {r['keyframes_asked']} | {', '.join(f'{y:+.0f}' for y in r['keyframe_yaws_deg'])} | "
                     f"{r['clip']['neutral_mm']:.3f} | {ratio:.3f} | {best:.3f} | {'met' if ratio <= 0.8 and ratio < best else 'not met'} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scans", nargs="+", default=list(SCANS), choices=list(SCANS))
    parser.add_argument("--step", type=float, default=4.0, help="degrees of yaw between frames")
    parser.add_argument("--samples", type=int, default=16, help="Cycles samples a pixel")
    parser.add_argument("--work", type=Path, default=None, help="folder for the frames and the tracks (default: a temporary one)")
    parser.add_argument("--keyframes", nargs="+", type=int, default=[5], help="facegeo track's --keyframes (each tried)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    model = load_model()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        results = [bench_scan(name, model, args.step, args.samples, work, k) for name in args.scans for k in args.keyframes]
    print(markdown(results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
