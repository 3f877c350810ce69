"""The regressor's subcommands: ``train-regressor`` and ``make-synthetic-faces``
(:mod:`facegeo.regressor`). Nothing here imports transformers until a command that needs it runs;
``fit`` and ``reconstruct`` take the regressor as ``--regressor CKPT [--refine]``
(:func:`facegeo.commands.arguments.add_regressor_arguments`)."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from facegeo.commands.arguments import (
    COMMAND_LINE,
    Command,
    RegistryNames,
    add_device_argument,
    add_model_argument,
    add_seed_argument,
)
from facegeo.errors import InputError

__all__ = ["COMMANDS"]

#: ``train-regressor --landmarks``: the ground truth of a synthetic folder or a detector.
LANDMARK_TARGETS = RegistryNames("facegeo.landmarks.detectors", "DETECTORS", extra=("auto", "truth"))


def _train_arguments(tr: argparse.ArgumentParser) -> None:
    tr.add_argument("--images", type=Path, required=True, help="folder of face images (or a make-synthetic-faces folder)")
    tr.add_argument("--out", type=Path, required=True, help="run folder (created; an existing run is resumed)")
    tr.add_argument("--config", type=Path, default=None, help="JSON config (network, loss, train sections); default: the paper's settings")
    add_model_argument(tr)
    tr.add_argument("--landmarks", default="auto", choices=LANDMARK_TARGETS, metavar="NAME",
                    help="landmark targets, one of %(choices)s: auto = the ground truth of a synthetic folder, else hybrid detection; "
                    "truth = that ground truth; else a detector")
    tr.add_argument("--epochs", type=int, default=None, help="override train.epochs")
    tr.add_argument("--batch-size", type=int, default=None, help="override train.batch_size")
    tr.add_argument("--lr", type=float, default=None, help="override train.lr (AdamW)")
    tr.add_argument("--max-steps", type=int, default=None, help="stop after this many optimiser steps")
    tr.add_argument("--convnext-weights", type=Path, default=None, help="local ConvNeXt V2 folder (from_pretrained)")
    tr.add_argument("--dino-weights", type=Path, default=None, help="local DINOv3 ViT folder (from_pretrained)")
    tr.add_argument("--no-resume", action="store_true", help="start afresh even if OUT/last.pt exists")
    add_device_argument(tr)
    tr.add_argument("--workers", type=int, default=0, help="data-loading worker processes")
    tr.add_argument("--max-side", type=int, default=1024, help="downscale photos to this before cropping")


def _synthetic_arguments(syn: argparse.ArgumentParser) -> None:
    syn.add_argument("--out", type=Path, required=True, help="output folder (created)")
    syn.add_argument("--count", type=int, default=1000, help="number of images")
    syn.add_argument("--size", type=int, default=256, help="image side in pixels")
    syn.add_argument("--max-yaw", type=float, default=75.0, help="yaw is uniform in ±this (degrees)")
    add_seed_argument(syn)
    add_model_argument(syn)


def _run_train(args: argparse.Namespace) -> None:
    from facegeo.regressor.config import load_config
    from facegeo.regressor.training import train

    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
    config = load_config(args.config)
    for name in ("epochs", "batch_size", "lr"):
        if getattr(args, name) is not None:
            setattr(config.train, name, getattr(args, name))
    if args.convnext_weights is not None:
        config.network.convnext_weights = str(args.convnext_weights)
    if args.dino_weights is not None:
        config.network.dino_weights = str(args.dino_weights)
    config.check(COMMAND_LINE)
    if args.max_steps is not None and args.max_steps < 1:
        raise InputError(COMMAND_LINE, "--max-steps", "a positive number", str(args.max_steps))
    summary = train(args.images, args.out, config, model=args.model, landmarks=args.landmarks, resume=not args.no_resume,
                    device=args.device, workers=args.workers, max_side=args.max_side, max_steps=args.max_steps,
                    progress=sys.stderr.isatty())
    if summary["skipped"]:
        print(f"skipped {len(summary['skipped'])} images (listed in {args.out}/skipped.txt)")
    print(f"trained {summary['steps']} steps, {summary['epochs']} epochs on {summary['n_train']} images "
          f"({summary['n_val']} validation): train {json.dumps(summary['train'])}, validation {json.dumps(summary['val'])}")
    print(f"wrote {args.out}/last.pt, best.pt, metrics.csv")


def _run_synthetic(args: argparse.Namespace) -> None:
    from facegeo.model_files import load_model
    from facegeo.regressor.synthetic import make_synthetic_faces

    if args.count < 1 or not 32 <= args.size <= 4096:
        raise InputError(COMMAND_LINE, "--count/--size", "count >= 1 and 32 <= size <= 4096", f"{args.count}, {args.size}")
    make_synthetic_faces(args.out, args.count, load_model(args.model), args.size, args.seed, args.max_yaw,
                         progress=sys.stderr.isatty())
    print(f"wrote {args.count} faces and faces.npz to {args.out}")


COMMANDS = (
    Command(
        "train-regressor",
        help="train the MSSF regressor (ConvNeXt V2 + frozen DINOv3) on a folder of face images",
        description="Self-supervised training (88-point landmark, photometric, perceptual and regularisation losses; "
        "weights in the config file). Landmarks are detected once and cached in the run folder; unreadable or faceless "
        "images are skipped and listed in skipped.txt. Writes config.json, metrics.csv, last.pt (resumable) and best.pt. "
        "Backbone weights: local Hugging Face folders (--convnext-weights / $FACEGEO_CONVNEXT_WEIGHTS, "
        "--dino-weights / $FACEGEO_DINOV3_WEIGHTS); without them the backbones start random.",
        arguments=_train_arguments,
        run=_run_train,
    ),
    Command(
        "make-synthetic-faces",
        help="render random model instances with known parameters (training and test data for the regressor)",
        description="Random identity, expression, skin albedo, SH lighting, pose and background, rendered with the "
        "project's renderer; writes NNNNNN.png and faces.npz (parameters, 88 landmarks, cameras).",
        arguments=_synthetic_arguments,
        run=_run_synthetic,
    ),
)
