"""Choosing the landmark fit's priors on validation faces with 3-D ground truth (issue 13).

    python benchmarks/bench_fit_priors.py [--faces 28] [--plot benchmarks/out/fit_priors.png]

Data (:mod:`fit_validation`): "real-like" faces (realistic expression mixes in [0, 1], smooth
deformations outside the model space, detector-like landmark noise) and noiseless faces of the
model itself. A validation set (seed 1) picks the weights; a disjoint test set (seed 2) reports
them, beside the fit before this change (unbounded δ, λ = 1e-6, run from git in the same
process) and the mean shape. Columns: 3-D error of the face region / the mean shape's (mean,
max), share of faces whose lips and chin depth relative to the nose tip are all within 3 mm,
median reprojection RMS (px), median ms per fit, expression weights outside [0, 1].

Sweeps (error against weight): the expression prior's scale s_δ and rate 1/τ with the noise
re-estimated (the default), and a *uniform* prior weight (the noise fixed, no re-estimation),
which cannot serve the noisy and the noiseless faces at once.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
import types
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fit_validation import CAMERA, face_errors, make_faces  # noqa: E402

from facegeo import load_model  # noqa: E402
from facegeo.fitting import DEFAULT_PRIORS, FitPriors, fit_landmarks  # noqa: E402

#: The commit whose fit is the "before" row (the last one with unbounded expressions).
BEFORE = "0477a8f"


def previous_fit_landmarks():
    """``fit_landmarks`` of :data:`BEFORE`, loaded from git into a private module."""
    root = Path(__file__).resolve().parents[1]
    source = subprocess.run(["git", "show", f"{BEFORE}:facegeo/fitting.py"], cwd=root, capture_output=True, text=True, check=True).stdout
    module = types.ModuleType("facegeo_fitting_before")
    sys.modules[module.__name__] = module
    exec(compile(source, f"{BEFORE}:facegeo/fitting.py", "exec"), module.__dict__)
    return module.fit_landmarks


def evaluate(model, faces, fit) -> dict[str, float]:
    """Summary of ``fit(landmarks) -> Fit`` over ``faces``."""
    ratio, depth_ok, rms, ms, out = [], [], [], [], 0
    for face in faces:
        t0 = time.perf_counter()
        result = fit(face.landmarks)
        ms.append(1000 * (time.perf_counter() - t0))
        e = face_errors(model, result.shape_vertices, face.shape)
        ratio.append(e["rms"] / e["mean_rms"])
        depth_ok.append(max(v for k, v in e.items() if k.startswith("depth")) <= 3.0)
        rms.append(result.landmark_rms_px)
        out += int(((result.delta < -1e-6) | (result.delta > 1 + 1e-6)).sum())
    return {"ratio_mean": float(np.mean(ratio)), "ratio_max": float(np.max(ratio)), "depth_ok": float(np.mean(depth_ok)),
            "rms_px": float(np.median(rms)), "ms": float(np.median(ms)), "out_of_range": out}


def row(label: str, real: dict, own: dict) -> str:
    return (f"| {label} | {real['ratio_mean']:.3f} | {real['ratio_max']:.3f} | {100 * real['depth_ok']:.0f} % | {real['rms_px']:.2f} | "
            f"{real['out_of_range']} | {own['ratio_mean']:.3f} | {own['ratio_max']:.3f} | {own['rms_px']:.2f} | {real['ms']:.0f} |")


HEADER = ("| fit | real-like: 3-D err / mean's (mean) | (max) | lips+chin depth ≤ 3 mm | RMS px | δ outside [0,1] | "
          "own model: 3-D err / mean's (mean) | (max) | RMS px | ms per fit |\n|---|---|---|---|---|---|---|---|---|---|")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--faces", type=int, default=28, help="real-like faces per set (own-model faces: half)")
    parser.add_argument("--plot", type=Path, default=Path("benchmarks/out/fit_priors.png"))
    parser.add_argument("--test-only", action="store_true", help="skip the validation sweeps")
    args = parser.parse_args()
    torch.set_num_threads(1)
    model = load_model()
    sets = {seed: (make_faces(model, args.faces, seed, "real-like"), make_faces(model, args.faces // 2, seed + 100, "model")) for seed in (1, 2)}

    def both(seed: int, priors: FitPriors) -> tuple[dict, dict]:
        real, own = sets[seed]
        fit = lambda lm: fit_landmarks(model, lm, CAMERA, priors=priors)  # noqa: E731
        return evaluate(model, real, fit), evaluate(model, own, fit)

    if not args.test_only:
        sweep(args, model, both)
    print(f"\ntest set (seed 2), defaults {DEFAULT_PRIORS}\n")
    print(HEADER)
    real, own = sets[2]
    before = previous_fit_landmarks()
    print(row(f"before ({BEFORE}: δ unbounded, λ 1e-6)", evaluate(model, real, lambda lm: before(model, lm, CAMERA)),
              evaluate(model, own, lambda lm: before(model, lm, CAMERA))))
    print(row("MAP, defaults", *both(2, DEFAULT_PRIORS)), flush=True)


def sweep(args, model, both) -> None:
    """The validation sweeps (seed 1), their table and plot."""
    print(f"validation set (seed 1): {args.faces} real-like + {args.faces // 2} own-model faces\n")
    print(HEADER)
    curves: dict[str, list[tuple[float, dict, dict]]] = {"scale": [], "rate": [], "uniform": [], "floor": []}
    for scale in (0.25, 0.5, 1.0, 2.0):
        real, own = both(1, replace(DEFAULT_PRIORS, expression_scale=scale))
        curves["scale"].append((scale, real, own))
        print(row(f"s_δ = {scale}", real, own), flush=True)
    for rate in (0.0, 1.0, 2.0, 4.0, 8.0):
        real, own = both(1, replace(DEFAULT_PRIORS, expression_rate=rate))
        curves["rate"].append((rate, real, own))
        print(row(f"1/τ = {rate}", real, own), flush=True)
    for floor in (0.002, 0.004, 0.008):
        real, own = both(1, replace(DEFAULT_PRIORS, noise_floor=floor))
        curves["floor"].append((floor, real, own))
        print(row(f"σ floor = {floor}", real, own), flush=True)
    for noise in (0.003, 0.01, 0.02, 0.04):
        real, own = both(1, replace(DEFAULT_PRIORS, noise=noise, noise_rounds=0))
        curves["uniform"].append((noise, real, own))
        print(row(f"uniform: σ fixed at {noise}", real, own), flush=True)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(17, 3.8))
    for ax, (name, label) in zip(axes, [("scale", "expression scale s_δ"), ("rate", "expression rate 1/τ"), ("floor", "noise floor (iod)"),
                                        ("uniform", "fixed noise σ = uniform prior weight (iod)")]):
        xs = [c[0] for c in curves[name]]
        ax.plot(xs, [c[1]["ratio_mean"] for c in curves[name]], "o-", label="real-like: 3-D err / mean's")
        ax.plot(xs, [c[2]["ratio_mean"] for c in curves[name]], "s-", label="own model: 3-D err / mean's")
        ax.plot(xs, [c[1]["depth_ok"] for c in curves[name]], "^--", label="real-like: depth ≤ 3 mm share")
        ax.set(xlabel=label, xscale="log" if min(xs) > 0 else "linear")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    args.plot.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(args.plot, dpi=100)
    print(f"\nplot: {args.plot}")


if __name__ == "__main__":
    main()
