"""Regressor benchmarks: the ablation on synthetic faces, regressor against the current fit, and
the throughput / peak memory of the real default sizes on CPU.

    python benchmarks/bench_regressor.py ablation   --out /tmp/bench_regressor [--steps 300]
    python benchmarks/bench_regressor.py fits       --out /tmp/bench_regressor   # after ablation
    python benchmarks/bench_regressor.py throughput [--batch 8] [--repeats 3]

ablation: ``make-synthetic-faces`` renders 400 training and 80 test faces (128 px, yaw uniform in
±85°, its default expressions: sparse, among those landmarks can see); three tiny MSSF variants are trained with the same data, steps, batch and seed: ConvNeXt
only with the 68-point loss (the paper's "Baseline"), ConvNeXt only with the 88-point loss ("w/o
MSSF"), ConvNeXt + frozen DINOv3 with the 88-point loss ("Ours"). Test metrics, with the true
landmarks given for the crop: 3D error of the predicted shape (α, δ: identity and expression) to
the true one (face region, mm, after similarity alignment: tests/test_fitting.similarity_rms, as
in bench_fit.py; the mean shape, α = δ = 0, is the reference), landmark RMS (px of the 128 px
image) and times. No augmentation: at this budget it kept the pose error above what expressions
move the landmarks by (the same for all rows). Then ``fit`` (landmarks only, the current analysis-by-synthesis fit) against "Ours" on the
same test faces, split at |yaw| = 60°, and how often the hybrid detector finds the face there.

fits: on the same test faces, the current fit (solvePnP start), the "Ours" regressor alone, and
the landmark fit started from the regressor's prediction (``fit_landmarks(..., init=)``).

throughput: ConvNeXt V2 Base + DINOv3 ViT-B/16 at 224 px (random weights: the arithmetic is the
same), images/s of the forward pass (no gradient) and of a training step (forward, the landmark
loss, backward, AdamW), each in a fresh process so that its peak resident memory is its own.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from facegeo import fit, fit_landmarks, load_model, load_photo
from facegeo.camera import euler_from_rotation
from facegeo.regressor import RegressorConfig, load, make_synthetic_faces, train

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_fitting import similarity_rms  # noqa: E402  (one definition of the 3D error)

TINY_NETWORK = {"image_size": 64, "width": 32,
                "convnext": {"hidden_sizes": [8, 16, 32, 64], "depths": [1, 1, 1, 1]},
                "dino": {"hidden_size": 32, "num_hidden_layers": 4, "num_attention_heads": 2, "intermediate_size": 64}}
VARIANTS = {  # name: (DINOv3 branch, landmark loss)
    "Baseline (ConvNeXt, 68-point loss)": (False, "ibug68"),
    "w/o MSSF (ConvNeXt, 88-point loss)": (False, "hybrid88"),
    "Ours (ConvNeXt + frozen DINOv3, 88-point loss)": (True, "hybrid88"),
}


def evaluate_predictions(model, folder: Path, predict) -> list[dict]:
    """Per test face: |yaw|, 3D error (mm), landmark RMS (px) and seconds of ``predict``."""
    truth = np.load(folder / "faces.npz")
    face = model.face_mask
    rows = []
    for i, name in enumerate(truth["names"]):
        shape = model.shape(torch.from_numpy(truth["alpha"][i]), torch.from_numpy(truth["delta"][i])).numpy()
        photo = load_photo(folder / str(name))
        t0 = time.perf_counter()
        result = predict(photo, truth["landmarks"][i])
        seconds = time.perf_counter() - t0
        rows.append({"yaw": abs(euler_from_rotation(truth["rotation"][i])[0]), "error_mm": similarity_rms(result.shape_vertices[face], shape[face]),
                     "landmark_rms_px": result.landmark_rms_px, "seconds": seconds})
    return rows


def summary(rows: list[dict], low: float = 0.0, high: float = 1e9) -> dict:
    chosen = [r for r in rows if low <= r["yaw"] < high]
    return {"n": len(chosen), **{k: float(np.mean([r[k] for r in chosen])) for k in ("error_mm", "landmark_rms_px", "seconds")}}


def ablation(out: Path, steps: int) -> dict:
    model = load_model()
    train_dir, test_dir = out / "train", out / "test"
    if not (train_dir / "faces.npz").is_file():
        make_synthetic_faces(train_dir, 400, model, size=128, seed=100, max_yaw=85)
    if not (test_dir / "faces.npz").is_file():
        make_synthetic_faces(test_dir, 80, model, size=128, seed=200, max_yaw=85)
    face = model.face_mask
    truth = np.load(test_dir / "faces.npz")
    mean_rows = [{"yaw": abs(euler_from_rotation(r)[0]), "seconds": 0.0, "landmark_rms_px": float("nan"),
                  "error_mm": similarity_rms(model.mean_shape[face], model.shape(torch.from_numpy(a), torch.from_numpy(d)).numpy()[face])}
                 for a, d, r in zip(truth["alpha"], truth["delta"], truth["rotation"])]
    results = {"steps": steps, "load_average": os.getloadavg(), "variants": {},
               "mean_shape": {"all": summary(mean_rows), "yaw<60": summary(mean_rows, 0, 60), "yaw>=60": summary(mean_rows, 60)}}
    print("mean shape", json.dumps(results["mean_shape"]), flush=True)
    for name, (dino, scheme) in VARIANTS.items():
        network = dict(TINY_NETWORK, dino=TINY_NETWORK["dino"] if dino else None)
        config = RegressorConfig.from_dict({"network": network, "loss": {"pho": 0.0, "landmarks": scheme},
                                            "train": {"lr": 1e-3, "batch_size": 16, "epochs": 1000, "val_fraction": 0.0,
                                                      "checkpoint_every": 0, "seed": 0, "augment": False}})
        run = out / ("run_" + name.split()[0].lower().replace("/", ""))
        t0 = time.perf_counter()
        train(train_dir, run, config, model=model, progress=False, max_steps=steps, resume=False)
        train_seconds = time.perf_counter() - t0
        predictor = load(run / "last.pt", model=model)
        rows = evaluate_predictions(model, test_dir, lambda photo, lm: predictor(photo, landmarks=lm))
        with (run / "metrics.csv").open() as f:
            lan = [float(r["lan"]) for r in csv.DictReader(f) if r["split"] == "train"]
        results["variants"][name] = {"train_seconds": train_seconds, "train_lan_first10": float(np.mean(lan[:10])),
                                     "train_lan_last20": float(np.mean(lan[-20:])), "all": summary(rows),
                                     "yaw<60": summary(rows, 0, 60), "yaw>=60": summary(rows, 60)}
        print(name, json.dumps(results["variants"][name]), flush=True)
    fit_rows = evaluate_predictions(model, test_dir, lambda photo, lm: fit(photo, model=model, landmarks=lm, photometric=False))
    results["fit"] = {"all": summary(fit_rows), "yaw<60": summary(fit_rows, 0, 60), "yaw>=60": summary(fit_rows, 60)}
    print("fit", json.dumps(results["fit"]), flush=True)
    from facegeo.errors import NoFaceError
    from facegeo.landmarks import get_detector

    detector = get_detector("hybrid")
    found = {"yaw<60": [0, 0], "yaw>=60": [0, 0]}
    for i, name in enumerate(truth["names"]):
        key = "yaw<60" if abs(euler_from_rotation(truth["rotation"][i])[0]) < 60 else "yaw>=60"
        found[key][1] += 1
        try:
            detector.detect(load_photo(test_dir / str(name)).image)
            found[key][0] += 1
        except NoFaceError:
            pass
    results["hybrid_detection_found"] = found
    print("detection", json.dumps(found), flush=True)
    (out / "ablation.json").write_text(json.dumps(results, indent=1))
    return results


def compare_fits(out: Path) -> dict:
    """fit (solvePnP start) / regressor / regressor then the landmark fit from its prediction,
    on the ablation's test faces with the true landmarks, split at |yaw| = 60°."""
    model = load_model()
    test_dir = out / "test"
    predictor = load(out / "run_ours" / "last.pt", model=model)
    rows = {
        "fit (solvePnP start, current)": evaluate_predictions(model, test_dir, lambda photo, lm: fit(photo, model=model, landmarks=lm, photometric=False)),
        "regressor (Ours) alone": evaluate_predictions(model, test_dir, lambda photo, lm: predictor(photo, landmarks=lm)),
        "regressor + landmark fit from it": evaluate_predictions(model, test_dir, lambda photo, lm: fit_landmarks(model, lm, (p := predictor(photo, landmarks=lm)).camera, init=p)),
    }
    results = {name: {"all": summary(r), "yaw<60": summary(r, 0, 60), "yaw>=60": summary(r, 60)} for name, r in rows.items()}
    for name, r in results.items():
        print(name, json.dumps(r), flush=True)
    (out / "fits.json").write_text(json.dumps(results, indent=1))
    return results


def one_throughput(kind: str, batch: int, repeats: int) -> dict:
    """Measured in this process: images/s (min and median over repeats) and peak RSS (MiB)."""
    from facegeo.regressor.losses import Objective
    from facegeo.regressor.network import ModelSignature, MSSFRegressor

    model = load_model()
    config = RegressorConfig()
    net = MSSFRegressor(config.network, ModelSignature.of(model))
    size = config.network.image_size
    x = torch.rand(batch, 3, size, size)
    intrinsics = torch.tensor([[400.0, size / 2, size / 2]]).expand(batch, 3)
    landmarks = torch.rand(batch, 88, 2) * size * 0.6 + size * 0.2
    objective = Objective(model, config.loss, size)
    optimizer = torch.optim.AdamW(net.trainable_parameters(), lr=1e-4)
    times = []
    for _ in range(repeats + 1):  # the first is a warm-up
        t0 = time.perf_counter()
        if kind == "forward":
            net.eval()
            with torch.no_grad():
                net.predict(x, intrinsics)
        else:
            net.train()
            terms = objective(net.predict(x, intrinsics), x, intrinsics, landmarks)
            optimizer.zero_grad()
            terms["total"].backward()
            optimizer.step()
        times.append(time.perf_counter() - t0)
    rates = [batch / t for t in times[1:]]
    n_train = sum(p.numel() for p in net.trainable_parameters())
    n_all = sum(p.numel() for p in net.parameters())
    return {"kind": kind, "batch": batch, "threads": torch.get_num_threads(), "images_per_s_min": min(rates),
            "images_per_s_median": float(np.median(rates)), "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "parameters_trainable_m": n_train / 1e6, "parameters_total_m": n_all / 1e6}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    a = sub.add_parser("ablation")
    a.add_argument("--out", type=Path, default=Path("/tmp/bench_regressor"))
    a.add_argument("--steps", type=int, default=300)
    f = sub.add_parser("fits")
    f.add_argument("--out", type=Path, default=Path("/tmp/bench_regressor"))
    t = sub.add_parser("throughput")
    t.add_argument("--batch", type=int, default=8)
    t.add_argument("--repeats", type=int, default=3)
    t.add_argument("--one", choices=["forward", "train"], default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.what == "ablation":
        args.out.mkdir(parents=True, exist_ok=True)
        ablation(args.out, args.steps)
    elif args.what == "fits":
        compare_fits(args.out)
    elif args.one:
        print(json.dumps(one_throughput(args.one, args.batch, args.repeats)))
    else:
        print(f"load average: {os.getloadavg()}", flush=True)
        for kind in ("forward", "train"):
            for batch in sorted({1, args.batch}):
                out = subprocess.run([sys.executable, __file__, "throughput", "--one", kind, "--batch", str(batch),
                                      "--repeats", str(args.repeats)], capture_output=True, text=True, check=True)
                print(out.stdout.strip().splitlines()[-1], flush=True)


if __name__ == "__main__":
    main()
