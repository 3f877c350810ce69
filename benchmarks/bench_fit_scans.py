"""Fit every rendered view of the real head scans and measure the NoW-style error against the scan.

    python benchmarks/bench_fit_scans.py [--scans james] [--true-camera] [--json OUT.json]
                                         [--fitter MODULE:FACTORY] [--scan-landmarks detected|annotation]
                                         [--sections DIR] [--views NAME ...]

For each scan of :data:`head_scans.SCANS` whose scale is measured (``--scans`` takes the others too): the views of :mod:`scan_renders` are rendered (once;
cached in ``~/.cache/facegeo/scans``), the scan's 68 landmarks are found (default ``detected``:
facegeo's hybrid detector on the frontal render, each point back-projected onto the scan by ray
casting with the true camera; rays that miss the scan (jaw points on the silhouette) take the scan
vertex projecting nearest; ``annotation``: the landmarks shipped with the scan), and the scan is
prepared once (:func:`scan_evaluation.prepare_scan`: samples within 95 mm of the nose tip). Then
every view is fitted WITHOUT the true focal (the fitter's default camera) and, with
``--true-camera``, also with the true intrinsics, and evaluated (:func:`scan_evaluation.evaluate`).

Baselines, aligned and measured the same way: the model's mean shape (α = 0, δ = 0; the same for
every view) and the mean identity with the fit's expression (α = 0, δ = the fit's). "ratio" is the
fit's mean distance over the mean shape's; "keypoint scale" the similarity step's scale (the
factor the prediction is enlarged by to meet the scan's 7 keypoints; kept through the ICP).
Pose: the fitted rotation of each view relative to the frontal view (``yaw+00``, same camera
mode) against the true relative rotation
(:func:`scan_evaluation.relative_rotation_error`).

The fitter is pluggable: ``--fitter MODULE:FACTORY`` imports FACTORY (a callable with no
arguments) from MODULE (importable from benchmarks/ or the path) and calls it once; it must
return a :data:`scan_evaluation.ScanFitter`: ``fitter(image_path, camera) -> Prediction`` with
``camera`` None when the focal is not to be given. The default is :func:`facegeo_fitter`
(``facegeo.fit`` with the hybrid detector; the photometric stage is skipped: it does not change
the geometry). A prediction's ``info["delta"]`` (the ICT expression weights), when present,
gives the "mean + δ" baseline.

``--sections DIR`` saves, per scan, camera mode and view, ``DIR/<scan>_<mode>_<view>.png``: three
sections of the scan (black), the aligned mean shape (blue) and the aligned fit (red) in the scan's
face frame (midsagittal, horizontal through the nose tip, horizontal through the mouth), mm.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from head_scans import SCANS, load_scan  # noqa: E402
from scan_evaluation import (  # noqa: E402
    DEPTH_PROBES, REGIONS, Prediction, ScanFitter, ScanReference, align_to_scan, evaluate, prepare_scan,
    relative_rotation_error,
)
from scan_renders import load_view, render_views, view_names, cast_rays  # noqa: E402

from facegeo import Camera, MorphableModel, load_model, project  # noqa: E402

FRONTAL = "yaw+00"


def facegeo_fitter(model: MorphableModel | None = None, detector: str = "hybrid") -> ScanFitter:
    """facegeo's analysis-by-synthesis fit as a :data:`ScanFitter` (photometric stage skipped)."""
    from facegeo import fit

    model = load_model() if model is None else model

    def run(image_path: Path, camera: Camera | None) -> Prediction:
        result = fit(image_path, model, detector=detector, camera=camera, photometric=False)
        return Prediction(vertices=result.shape_vertices, triangles=model.triangles,
                          landmark_vertices=model.landmark_indices, rotation=result.rotation,
                          info={"delta": result.delta, "alpha_norm": float(np.linalg.norm(result.alpha)),
                                "landmark_rms_px": result.landmark_rms_px, "focal_px": result.camera.focal})

    return run


def scan_landmarks(scan_name: str, how: str) -> tuple[np.ndarray, dict]:
    """(68, 3) mm scan landmarks (iBUG order) and a record of how they were found."""
    scan = load_scan(scan_name)
    if how == "annotation":
        return scan.annotation, {"how": "annotation"}
    from facegeo.landmarks import get_detector

    view = load_view(scan_name, FRONTAL)
    pixels = get_detector("hybrid").detect(view.image, str(view.image_path)).points[:68].astype(np.float64)
    points, _ = cast_rays(scan.vertices, scan.triangles, view.rotation, view.translation, view.camera, pixels)
    points = points.astype(np.float64)
    missed = np.flatnonzero(~np.isfinite(points[:, 0]))
    if len(missed):
        projected = project(scan.vertices, view.rotation, view.translation, view.camera)
        for k in missed:
            points[k] = scan.vertices[np.argmin(np.linalg.norm(projected - pixels[k], axis=1))]
    record = {"how": "detected on the frontal render, back-projected", "missed_rays": missed.tolist()}
    if scan.annotation is not None:
        gap = np.linalg.norm(points - scan.annotation, axis=1)
        record["distance_to_annotation_mm"] = {"inner face (17-67) median": float(np.median(gap[17:])),
                                               "inner face max": float(gap[17:].max()),
                                               "jaw (0-16) median": float(np.median(gap[:17]))}
    return points, record


def save_sections(path: Path, reference: ScanReference, meshes: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    """A PNG of three sections (face frame, mm) through the scan and ``meshes`` ({label: (aligned
    vertices (V, 3), triangles (F, 3))}, drawn in the order given after the scan)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import trimesh

    frame, origin = reference.frame, reference.landmarks[30]
    cuts = [("midsagittal (z, y)", frame[0], origin, (2, 1)),
            ("horizontal through the nose tip (x, z)", frame[1], origin, (0, 2)),
            ("horizontal through the mouth (x, z)", frame[1], reference.landmarks[62], (0, 2))]
    colours = ["k", "tab:blue", "tab:red", "tab:green", "tab:purple"]
    figure, axes = plt.subplots(1, 3, figsize=(15, 6))
    everything = {"scan": (reference.vertices, reference.triangles), **meshes}
    for ax, (title, normal, through, (a, b)) in zip(axes, cuts):
        for colour, (label, (vertices, triangles)) in zip(colours, everything.items()):
            section = trimesh.Trimesh(vertices, triangles, process=False).section(plane_origin=through, plane_normal=normal)
            if section is None:
                continue
            for k, entity in enumerate(section.entities):
                local = (section.vertices[entity.points] - origin) @ frame.T
                ax.plot(local[:, a], local[:, b], color=colour, lw=2 if label == "scan" else 1,
                        label=label if k == 0 else None)
        ax.set_title(title)
        ax.set_aspect("equal")
        ax.set_xlim(-110, 110) if a == 0 else ax.set_xlim(-140, 40)
        if a != 0:
            ax.set_ylim(-120, 80)
        ax.legend(fontsize=8)
    figure.savefig(path, dpi=70)
    plt.close(figure)


def _mean_with_delta(model: MorphableModel, delta: np.ndarray) -> np.ndarray:
    import torch

    alpha = torch.zeros(model.n_id, dtype=torch.float32)
    return model.shape(alpha, torch.as_tensor(np.asarray(delta, np.float32))).numpy()


def bench_scan(scan_name: str, fitter: ScanFitter, model: MorphableModel, camera_modes: list[str],
               landmarks_how: str, sections: Path | None = None, views: list[str] | None = None) -> dict:
    """The views of one scan (``views``: these and the frontal one; None: all): errors, baselines
    and pose errors per camera mode (section plots into ``sections`` when given)."""
    render_views(scan_name)
    landmarks, landmark_record = scan_landmarks(scan_name, landmarks_how)
    scan = load_scan(scan_name)
    reference: ScanReference = prepare_scan(scan.vertices, scan.triangles, landmarks)
    mean_prediction = Prediction(model.mean_shape, model.triangles, model.landmark_indices)
    mean_result = evaluate(mean_prediction, reference)
    out = {"scan": scan_name, "licence": scan.source.licence, "attribution": scan.source.attribution,
           "landmarks": landmark_record, "n_samples": int(len(reference.samples)),
           "region_samples": {name: int((reference.regions == k).sum()) for k, name in enumerate(REGIONS)},
           "mean_shape": mean_result, "modes": {}}
    for mode in camera_modes:
        rows = {}
        for name in [n for n in view_names() if views is None or n in views or n == FRONTAL]:
            view = load_view(scan_name, name)
            t0 = time.perf_counter()
            prediction = fitter(view.image_path, view.camera if mode == "true" else None)
            seconds = time.perf_counter() - t0
            result = evaluate(prediction, reference)
            row = {"view": name, "light": view.light, "lens_mm": view.lens_mm, "fit": result, "fit_seconds": seconds,
                   "ratio": result["mean"] / mean_result["mean"],
                   "info": {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in prediction.info.items()},
                   "rotation": None if prediction.rotation is None else np.asarray(prediction.rotation).tolist(),
                   "true_rotation": view.rotation.tolist()}
            if "delta" in prediction.info:
                with_delta = Prediction(_mean_with_delta(model, prediction.info["delta"]), model.triangles,
                                        model.landmark_indices)
                row["mean_with_delta"] = evaluate(with_delta, reference)
            rows[name] = row
            if sections is not None:
                sections.mkdir(parents=True, exist_ok=True)
                save_sections(sections / f"{scan_name}_{mode}_{name}.png", reference,
                              {"mean shape": (align_to_scan(mean_prediction, reference)[0], model.triangles),
                               "fit": (align_to_scan(prediction, reference)[0], prediction.triangles)})
            print(f"{scan_name} {mode:7s} {name:9s} mean {result['mean']:.2f} mm (mean shape {mean_result['mean']:.2f}), "
                  f"{seconds:.1f} s", file=sys.stderr)
        frontal = rows[FRONTAL]
        for row in rows.values():
            if row["rotation"] is not None and frontal["rotation"] is not None:
                row["pose_error_deg"] = relative_rotation_error(row["rotation"], frontal["rotation"], row["true_rotation"],
                                                                frontal["true_rotation"])
                # against the truth in the model's frame: the true rotation less the scan's frontal
                # rotation (the frontal view's, which turns the scan's landmarks onto the mean shape's)
                row["absolute_euler_error_deg"] = relative_rotation_error(row["rotation"], np.eye(3), row["true_rotation"],
                                                                          frontal["true_rotation"])
        out["modes"][mode] = rows
    return out


def _f(x: float, digits: int = 2) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def markdown(results: list[dict]) -> str:
    """The tables of RESULTS.md."""
    lines = []
    for res in results:
        mean = res["mean_shape"]
        for mode, rows in res["modes"].items():
            camera = "default camera (focal not given)" if mode == "default" else "true camera given"
            lines += [f"**{res['scan']}, {camera}.** Mean shape (α = 0, δ = 0): median {_f(mean['median'])}, "
                      f"mean {_f(mean['mean'])}, RMSE {_f(mean['rmse'])} mm, keypoint scale "
                      f"{_f(mean['alignment']['scale'], 3)}.", "",
                      "| view | light, lens | median mm | mean mm | RMSE mm | mean shape + fit's δ: mean mm "
                      "| fit / mean shape (mean) | keypoint scale | ‖α‖ | landmark RMS px | focal used px "
                      "| pose err yaw / pitch / roll ° |",
                      "|---|---|---|---|---|---|---|---|---|---|---|---|"]
            for name, row in rows.items():
                fit = row["fit"]
                delta = row.get("mean_with_delta", {}).get("mean")
                pose = row.get("pose_error_deg")
                pose_text = "(reference)" if name == FRONTAL else (
                    f"{pose['yaw']:+.1f} / {pose['pitch']:+.1f} / {pose['roll']:+.1f}" if pose else "–")
                lines.append(f"| {name} | {row['light']}, {row['lens_mm']:.0f} mm | {_f(fit['median'])} | {_f(fit['mean'])} | "
                             f"{_f(fit['rmse'])} | {_f(delta)} | {_f(row['ratio'], 3)} | {_f(fit['alignment']['scale'], 3)} | "
                             f"{_f(row['info'].get('alpha_norm', float('nan')), 1)} | "
                             f"{_f(row['info'].get('landmark_rms_px', float('nan')))} | "
                             f"{_f(row['info'].get('focal_px', float('nan')), 0)} | {pose_text} |")
            ratios = [row["ratio"] for row in rows.values()]
            angles = [row["pose_error_deg"]["angle"] for n, row in rows.items() if n != FRONTAL and "pose_error_deg" in row]
            lines += ["", f"Median over views: fit / mean shape {np.median(ratios):.3f} (min {min(ratios):.3f}, max "
                      f"{max(ratios):.3f}); relative-rotation error {np.median(angles):.1f}° (max {max(angles):.1f}°).", ""]
            lines += ["| view | " + " | ".join(REGIONS) + " | " + " | ".join(f"{p} depth" for p in DEPTH_PROBES) + " |",
                      "|---|" + "---|" * (len(REGIONS) + 3)]
            lines.append("| mean shape | " + " | ".join(_f(mean["regions"][r]) for r in REGIONS) + " | "
                         + " | ".join(f"{mean['depth'][p]:+.1f}" for p in DEPTH_PROBES) + " |")
            for name, row in rows.items():
                fit = row["fit"]
                lines.append(f"| {name} | " + " | ".join(_f(fit["regions"][r]) for r in REGIONS) + " | "
                             + " | ".join(f"{fit['depth'][p]:+.1f}" for p in DEPTH_PROBES) + " |")
            lines.append("")
    return "\n".join(lines)


def _load_fitter(spec: str | None) -> ScanFitter:
    if spec is None:
        return facegeo_fitter()
    module_name, _, factory = spec.partition(":")
    return getattr(importlib.import_module(module_name), factory)()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scans", nargs="+", default=[n for n, s in SCANS.items() if s.metric], choices=list(SCANS),
                        help="default: the scans whose millimetres are measured (lee_perry_smith's are estimated from the "
                             "ICT mean shape: its errors are in those millimetres; the ratio to the mean shape holds)")
    parser.add_argument("--true-camera", action="store_true", help="also fit every view with the true intrinsics")
    parser.add_argument("--fitter", help="MODULE:FACTORY returning a ScanFitter (default: facegeo.fit)")
    parser.add_argument("--scan-landmarks", choices=("detected", "annotation"), default="detected")
    parser.add_argument("--json", type=Path, help="write every number here")
    parser.add_argument("--sections", type=Path, help="save section plots (scan, mean shape, fit) per view here")
    parser.add_argument("--views", nargs="+", choices=view_names(), help="only these views (and the frontal one)")
    args = parser.parse_args()
    model = load_model()
    fitter = _load_fitter(args.fitter)
    modes = ["default", "true"] if args.true_camera else ["default"]
    results = [bench_scan(name, fitter, model, modes, args.scan_landmarks, args.sections, args.views) for name in args.scans]
    print(markdown(results))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=1, default=float))


if __name__ == "__main__":
    main()
