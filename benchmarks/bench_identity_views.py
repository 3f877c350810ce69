"""One identity from several views of a real head scan: the joint fit against each view's own fit.

    python benchmarks/bench_identity_views.py [--scans james lee_perry_smith] [--views yaw+00 yaw-20 ...]
                                              [--precisions 1 5] [--iterations 6 12 24] [--weights 0 200]
                                              [--repeat 3] [--json OUT.json]

For each head scan of :mod:`head_scans` (both by default: the ratio to the mean shape holds in
Lee Perry-Smith's estimated millimetres too) the views of :mod:`scan_renders` are rendered
(once, Blender, cached) and measured NoW-style against the scan (:mod:`scan_evaluation`, the
scan's landmarks detected on the frontal render as in ``bench_fit_scans.py``):

* the model's mean shape (α = 0, δ = 0);
* each view fitted alone (:func:`facegeo.fit`, focal not given, photometric stage skipped);
* the mean of those single-view identities, with the frontal view's δ (the "average the
  separate fits" baseline the issue measured);
* the views fitted jointly (:func:`facegeo.fitting.fit_photos`: one α, pose and δ per view),
  evaluated with the frontal view's δ, for each identity prior precision c of ``--precisions``
  (:mod:`facegeo.fitting.shared_identity`; 0 stands for the default, the number of views), with the
  views' colours at each weight of ``--weights`` (:mod:`facegeo.fitting.view_consistency`; 0: the
  landmarks alone).

"ratio" is a prediction's mean scan-to-mesh distance over the mean shape's, with the prediction's
own expression and neutral (δ = 0: the identity alone). ``--iterations`` reports the joint fit's
error against its run time for the knob of its Levenberg–Marquardt rounds (min and median of
``--repeat`` runs).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fit_scans import FRONTAL, scan_landmarks  # noqa: E402
from head_scans import SCANS, load_scan  # noqa: E402
from scan_evaluation import Prediction, ScanReference, evaluate, prepare_scan  # noqa: E402
from scan_renders import load_view, render_views  # noqa: E402

from facegeo import MorphableModel, load_model  # noqa: E402

HEAD_TURN = ["yaw+00", "yaw-20", "yaw+20", "yaw-40", "yaw+40"]


def _prediction(model: MorphableModel, alpha: np.ndarray, delta: np.ndarray) -> Prediction:
    import torch

    vertices = model.shape(torch.as_tensor(np.asarray(alpha, np.float32)), torch.as_tensor(np.asarray(delta, np.float32))).numpy()
    return Prediction(vertices, model.triangles, model.landmark_indices)


def _ratios(model: MorphableModel, reference: ScanReference, mean: float, alpha: np.ndarray, delta: np.ndarray) -> dict:
    """Mean scan distance (mm) with ``delta`` and neutral, and both over the mean shape's."""
    with_delta = evaluate(_prediction(model, alpha, delta), reference)["mean"]
    neutral = evaluate(_prediction(model, alpha, np.zeros(model.n_exp)), reference)["mean"]
    return {"mean_mm": with_delta, "ratio": with_delta / mean, "neutral_mm": neutral, "neutral_ratio": neutral / mean}


def bench_scan(scan_name: str, model: MorphableModel, views: list[str], precisions: list[float], iterations: list[int],
               repeat: int, weights: list[float]) -> dict:
    """Errors of the mean shape, the single-view fits, their mean identity and the joint fits."""
    from facegeo import fit
    from facegeo.fitting import DEFAULT_PRIORS
    from facegeo.fitting.photo_fit import observe_photo
    from facegeo.fitting.shared_identity import LandmarkView, solve_shared_identity
    from facegeo.fitting.view_consistency import ConsistencySettings

    render_views(scan_name)
    landmarks, _ = scan_landmarks(scan_name, "detected")
    scan = load_scan(scan_name)
    reference = prepare_scan(scan.vertices, scan.triangles, landmarks)
    mean = evaluate(Prediction(model.mean_shape, model.triangles, model.landmark_indices), reference)["mean"]
    out: dict = {"scan": scan_name, "views": views, "mean_shape_mm": mean, "single": {}, "joint": []}
    singles = {}
    for name in views:
        t0 = time.perf_counter()
        result = fit(load_view(scan_name, name).image_path, model, photometric=False)
        seconds = time.perf_counter() - t0
        singles[name] = result
        out["single"][name] = {**_ratios(model, reference, mean, result.alpha, result.delta), "seconds": seconds}
        print(f"{scan_name} single {name}: ratio {out['single'][name]['ratio']:.3f}, {seconds:.2f} s", file=sys.stderr)
    frontal = singles[FRONTAL] if FRONTAL in singles else singles[views[0]]
    out["mean_of_singles"] = _ratios(model, reference, mean, np.mean([r.alpha for r in singles.values()], axis=0), frontal.delta)
    seen = [observe_photo(load_view(scan_name, name).image_path, model) for name in views]
    first = views.index(FRONTAL) if FRONTAL in views else 0
    for precision, its, weight in ((p, i, w) for p in precisions for i in iterations for w in weights):
        times = []
        consistency = ConsistencySettings(weight=weight) if weight > 0 else None
        for _ in range(repeat):
            t0 = time.perf_counter()
            solutions = solve_shared_identity(model, [LandmarkView.of(s) for s in seen], DEFAULT_PRIORS, iterations=its,
                                              identity_precision=precision or None, consistency=consistency)
            times.append(time.perf_counter() - t0)
        joint = solutions[first].fit
        row = {**_ratios(model, reference, mean, joint.alpha, joint.delta), "iterations": its, "colours_weight": weight,
               "identity_precision": joint.info["shared_identity"]["identity_precision"],
               "seconds_min": min(times), "seconds_median": float(np.median(times)),
               "steps": joint.info["shared_identity"]["joint_steps"],
               "noise_iod_fraction": joint.info["shared_identity"]["noise_iod_fraction"]}
        out["joint"].append(row)
        print(f"{scan_name} joint c={row['identity_precision']:g}, {its} iterations, colours {weight:g}: neutral ratio "
              f"{row['neutral_ratio']:.3f}, {min(times):.2f} s", file=sys.stderr)
    return out


def markdown(results: list[dict]) -> str:
    """The tables of RESULTS.md."""
    lines = []
    for res in results:
        lines += [f"**{res['scan']}** (mean shape {res['mean_shape_mm']:.3f} mm)", "",
                  "| prediction | mean mm | / mean shape | neutral: / mean shape | seconds (min / median) |",
                  "|---|---:|---:|---:|---:|"]
        for name, row in res["single"].items():
            lines.append(f"| {name} alone | {row['mean_mm']:.3f} | {row['ratio']:.3f} | {row['neutral_ratio']:.3f} | "
                         f"{row['seconds']:.2f} |")
        row = res["mean_of_singles"]
        lines.append(f"| mean of the single-view identities | {row['mean_mm']:.3f} | {row['ratio']:.3f} | "
                     f"{row['neutral_ratio']:.3f} | |")
        for row in res["joint"]:
            colours = f"colours weight {row['colours_weight']:g}" if row.get("colours_weight") else "landmarks only"
            lines.append(f"| joint, {len(res['views'])} views, c = {row['identity_precision']:g}, {row['iterations']} iterations "
                         f"(steps {row['steps']}), {colours} | {row['mean_mm']:.3f} | {row['ratio']:.3f} | {row['neutral_ratio']:.3f} | "
                         f"{row['seconds_min']:.2f} / {row['seconds_median']:.2f} |")
        best = min(row["ratio"] for row in res["single"].values())
        lines += ["", f"Best single view: {best:.3f} of the mean shape.", ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scans", nargs="+", default=list(SCANS), choices=list(SCANS))
    parser.add_argument("--views", nargs="+", default=HEAD_TURN)
    parser.add_argument("--precisions", nargs="+", type=float, default=[1.0, 0.0],
                        help="identity prior precisions c of the joint fit (0: the default, the number of views)")
    parser.add_argument("--iterations", nargs="+", type=int, default=[12])
    parser.add_argument("--weights", nargs="+", type=float, default=[0.0, 200.0],
                        help="weights of the views' colours (facegeo.fitting.view_consistency; 0: landmarks only)")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    model = load_model()
    results = [bench_scan(name, model, args.views, args.precisions, args.iterations, args.repeat, args.weights)
               for name in args.scans]
    print(markdown(results))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=1, default=float))


if __name__ == "__main__":
    main()
