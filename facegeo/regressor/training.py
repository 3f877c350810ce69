"""Self-supervised training of the MSSF regressor (``facegeo train-regressor``).

The run folder holds: ``config.json`` (the effective config), ``landmarks.npz`` (landmarks
detected once per image), ``skipped.txt`` (images left out and why), ``metrics.csv`` (one row per
training step and per validation pass), ``last.pt`` (everything needed to resume) and ``best.pt``
(the network with the lowest validation loss). AdamW with a constant learning rate; gradients
clipped; bfloat16 autocast on a GPU. The data order and the augmentation are functions of
(seed, epoch, index), so a resumed run continues the same loss curve.
"""

from __future__ import annotations

import csv
import json
import logging
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch

from facegeo.errors import InputError
from facegeo.model_files import load_model
from facegeo.morphable_model import MorphableModel
from facegeo.regressor.config import RegressorConfig
from facegeo.regressor.data import TRUTH_FILE, FaceCrops, landmark_table, list_images, split_names
from facegeo.regressor.losses import Objective
from facegeo.regressor.network import ModelSignature, MSSFRegressor
from facegeo.regressor.predictor import network_from_checkpoint, read_checkpoint, save_checkpoint
from facegeo.staged_output import atomic_write_text

__all__ = ["train", "evaluate", "METRIC_FIELDS"]

log = logging.getLogger("facegeo.regressor")

METRIC_FIELDS = ["epoch", "step", "split", "total", "lan", "pho", "per", "reg", "lr", "seconds"]


def _batches(n: int, batch_size: int, seed: int, epoch: int) -> list[list[int]]:
    order = torch.randperm(n, generator=torch.Generator().manual_seed(seed * 1_000_003 + epoch)).tolist()
    return [order[i:i + batch_size] for i in range(0, n, batch_size)]


def _loader(dataset: FaceCrops, batches: list[list[int]], workers: int) -> Iterator[dict[str, torch.Tensor]]:
    return iter(torch.utils.data.DataLoader(dataset, batch_sampler=batches, num_workers=workers))


def evaluate(network: MSSFRegressor, objective: Objective, dataset: FaceCrops, batch_size: int = 16,
             device: str = "cpu") -> dict[str, float]:
    """Mean of each loss term over ``dataset`` (no gradient, the network in eval mode)."""
    was_training = network.training
    network.eval()
    sums: dict[str, float] = {}
    count = 0
    with torch.no_grad():
        for batch in _loader(dataset, [list(range(i, min(i + batch_size, len(dataset)))) for i in range(0, len(dataset), batch_size)], 0):
            terms = _step_terms(network, objective, batch, device)
            n = len(batch["image"])
            for k in ("lan", "pho", "per", "reg"):
                sums[k] = sums.get(k, 0.0) + float(terms[k].sum())
            sums["total"] = sums.get("total", 0.0) + float(terms["total"]) * n
            count += n
    network.train(was_training)
    return {k: v / max(count, 1) for k, v in sums.items()}


def _step_terms(network: MSSFRegressor, objective: Objective, batch: dict[str, torch.Tensor], device: str) -> dict[str, torch.Tensor]:
    image = batch["image"].to(device)
    with torch.autocast("cuda", dtype=torch.bfloat16, enabled=device.startswith("cuda")):
        raw = network(image)
    params = {k: v.float().cpu() for k, v in network.decode(raw.float(), batch["intrinsics"].to(device)).items()}
    return objective(params, batch["image"], batch["intrinsics"], batch["landmarks"])


def _rewind_metrics(path: Path, step: int) -> None:
    """Drop the rows written after the checkpoint a run resumes from."""
    if not path.is_file():
        return
    with path.open(newline="") as f:
        rows = [r for r in csv.DictReader(f) if int(r["step"]) <= step]
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=METRIC_FIELDS)
        writer.writeheader()
        writer.writerows(rows)


def train(images: str | Path, run: str | Path, config: RegressorConfig | None = None, *,
          model: MorphableModel | str | Path | None = None, landmarks: str = "auto", resume: bool = True,
          device: str | None = None, workers: int = 0, max_side: int = 1024, max_steps: int | None = None,
          progress: bool = True) -> dict[str, Any]:
    """Train (or resume) a regressor on a folder of face images.

    Args:
        images: folder of photos (or a ``make-synthetic-faces`` folder).
        run: the run folder (created). config: default :class:`RegressorConfig`.
        model: the morphable model or its file (default: the bundled one).
        landmarks: ``auto`` (the ground truth of a synthetic folder, else ``hybrid``),
            ``truth``, or a detector name.
        resume: continue from ``run/last.pt`` when it exists (its network and loss sections
            win; the train section is ``config``'s when given).
        device: ``cuda`` / ``cpu`` (default: cuda when available). workers: DataLoader workers.
        max_side: photos are downscaled to this before cropping. max_steps: stop after this
            many optimiser steps in total (None: run all epochs).
    Returns:
        A summary: steps, epochs, the last training and validation terms, skipped images, paths.
    """
    from tqdm import tqdm

    device = device or ("cuda" if torch.cuda.is_available() else "cpu")
    run = Path(run)
    run.mkdir(parents=True, exist_ok=True)
    model = model if isinstance(model, MorphableModel) else load_model(model)
    last = run / "last.pt"
    payload = read_checkpoint(last) if resume and last.is_file() else None
    if payload is not None:  # the run's network and loss; the train section as given (if given)
        network, stored = network_from_checkpoint(payload, last, model)
        if config is not None:
            stored.train = config.train
        config = stored
    else:
        config = config or RegressorConfig()
        config.check()
        with torch.random.fork_rng():  # the same seed gives the same initial network
            torch.manual_seed(config.train.seed)
            network = MSSFRegressor(config.network, ModelSignature.of(model))
    network.to(device).train()
    atomic_write_text(run / "config.json", json.dumps(config.to_dict(), indent=1))
    tc = config.train

    files = list_images(images)
    if landmarks == "auto":
        landmarks = "truth" if (Path(images) / TRUTH_FILE).is_file() else "hybrid"
    table, skipped = landmark_table(files, run / "landmarks.npz", landmarks, max_side, progress)
    atomic_write_text(run / "skipped.txt", "".join(f"{name}\t{why}\n" for name, why in skipped))
    for name, why in skipped:
        log.warning("skipped %s: %s", name, why)
    train_names, val_names = split_names(sorted(table), tc.val_fraction, tc.seed)
    if not train_names:
        raise InputError(images, "images", "at least one usable training image", f"none ({len(skipped)} skipped)")
    size, scale = config.network.image_size, config.network.crop_scale
    train_set = FaceCrops([table[n] for n in train_names], size, scale, tc.augment, tc.seed, max_side)
    val_set = FaceCrops([table[n] for n in val_names], size, scale, False, tc.seed, max_side)
    objective = Objective(model, config.loss, size)
    optimizer = torch.optim.AdamW(network.trainable_parameters(), lr=tc.lr, weight_decay=tc.weight_decay)
    step, epoch, skip, best = 0, 0, 0, float("inf")
    if payload is not None:
        optimizer.load_state_dict(payload["optimizer"])
        step, epoch, skip, best = payload["step"], payload["epoch"], payload["batch_in_epoch"], payload["best"]
    metrics = run / "metrics.csv"
    _rewind_metrics(metrics, step)
    new_file = not metrics.is_file()
    with metrics.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=METRIC_FIELDS)
        if new_file:
            writer.writeheader()

        def checkpoint(epoch_now: int, batch_now: int) -> None:
            save_checkpoint(last, network, config, optimizer=optimizer.state_dict(), step=step, epoch=epoch_now,
                            batch_in_epoch=batch_now, best=best)

        per_epoch = -(-len(train_set) // tc.batch_size)
        total_steps = tc.epochs * per_epoch if max_steps is None else min(max_steps, tc.epochs * per_epoch)
        bar = tqdm(total=total_steps, initial=step, desc="train-regressor", unit="step", disable=not progress)
        terms: dict[str, torch.Tensor] = {}
        val: dict[str, float] = {}
        while epoch < tc.epochs and step < total_steps:
            train_set.epoch = epoch
            batches = _batches(len(train_set), tc.batch_size, tc.seed, epoch)
            b = skip - 1
            for b, batch in enumerate(_loader(train_set, batches[skip:], workers), start=skip):
                t0 = time.perf_counter()
                terms = _step_terms(network, objective, batch, device)
                optimizer.zero_grad(set_to_none=True)
                terms["total"].backward()
                torch.nn.utils.clip_grad_norm_(network.trainable_parameters(), tc.max_grad_norm)
                optimizer.step()
                step += 1
                writer.writerow({"epoch": epoch, "step": step, "split": "train", "lr": tc.lr,
                                 "seconds": round(time.perf_counter() - t0, 4), "total": terms["total"].item(),
                                 **{k: terms[k].mean().item() for k in ("lan", "pho", "per", "reg")}})
                bar.update(1)
                bar.set_postfix(loss=f"{terms['total'].item():.4g}", epoch=epoch)
                if step >= total_steps:
                    break
                if tc.checkpoint_every and step % tc.checkpoint_every == 0 and b + 1 < len(batches):
                    f.flush()
                    checkpoint(epoch, b + 1)
            finished_epoch = b + 1 == len(batches)
            skip = 0
            if finished_epoch:
                epoch += 1
                if len(val_set):
                    val = evaluate(network, objective, val_set, tc.batch_size, device)
                    writer.writerow({"epoch": epoch - 1, "step": step, "split": "val", "lr": tc.lr, "seconds": 0.0, **val})
                    if val["total"] < best:
                        best = val["total"]
                        save_checkpoint(run / "best.pt", network, config, step=step, epoch=epoch)
            f.flush()
            checkpoint(epoch, 0 if finished_epoch else b + 1)
        bar.close()
    if not (run / "best.pt").is_file():
        save_checkpoint(run / "best.pt", network, config, step=step, epoch=epoch)
    return {"steps": step, "epochs": epoch, "train": {k: float(v.detach().mean()) for k, v in terms.items()}, "val": val,
            "skipped": skipped, "n_train": len(train_set), "n_val": len(val_set), "run": str(run),
            "backbones_loaded": dict(network.loaded)}
