"""The regressor's subcommands (``train-regressor``, ``make-synthetic-faces``) and the
``--regressor CKPT [--refine]`` options of ``fit`` and ``reconstruct``. Nothing here imports
transformers until a command that needs it runs."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any

__all__ = ["register", "add_regressor_arguments"]


def add_regressor_arguments(parser: argparse.ArgumentParser) -> None:
    """``--regressor CKPT`` and ``--refine`` (for ``fit`` and ``reconstruct``)."""
    parser.add_argument("--regressor", type=Path, default=None, metavar="CKPT",
                        help="use a trained regressor checkpoint (facegeo train-regressor) instead of the analysis-by-synthesis fit")
    parser.add_argument("--refine", action="store_true",
                        help="with --regressor: run the analysis-by-synthesis fit started from the prediction")


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``train-regressor`` and ``make-synthetic-faces`` to the ``facegeo`` parser."""
    tr = sub.add_parser(
        "train-regressor",
        help="train the MSSF regressor (ConvNeXt V2 + frozen DINOv3) on a folder of face images",
        description="Self-supervised training (88-point landmark, photometric, perceptual and regularisation losses; "
        "weights in the config file). Landmarks are detected once and cached in the run folder; unreadable or faceless "
        "images are skipped and listed in skipped.txt. Writes config.json, metrics.csv, last.pt (resumable) and best.pt. "
        "Backbone weights: local Hugging Face folders (--convnext-weights / $FACEGEO_CONVNEXT_WEIGHTS, "
        "--dino-weights / $FACEGEO_DINOV3_WEIGHTS); without them the backbones start random.",
    )
    tr.add_argument("--images", type=Path, required=True, help="folder of face images (or a make-synthetic-faces folder)")
    tr.add_argument("--out", type=Path, required=True, help="run folder (created; an existing run is resumed)")
    tr.add_argument("--config", type=Path, default=None, help="JSON config (network, loss, train sections); default: the paper's settings")
    tr.add_argument("--model", type=Path, default=None, help="model file (see 'facegeo fit --help')")
    tr.add_argument("--landmarks", default="auto", choices=["auto", "truth", "hybrid", "dlib", "mediapipe"],
                    help="landmark targets: auto = the ground truth of a synthetic folder, else hybrid detection")
    tr.add_argument("--epochs", type=int, default=None, help="override train.epochs")
    tr.add_argument("--batch-size", type=int, default=None, help="override train.batch_size")
    tr.add_argument("--lr", type=float, default=None, help="override train.lr (AdamW)")
    tr.add_argument("--max-steps", type=int, default=None, help="stop after this many optimiser steps")
    tr.add_argument("--convnext-weights", type=Path, default=None, help="local ConvNeXt V2 folder (from_pretrained)")
    tr.add_argument("--dino-weights", type=Path, default=None, help="local DINOv3 ViT folder (from_pretrained)")
    tr.add_argument("--no-resume", action="store_true", help="start afresh even if OUT/last.pt exists")
    tr.add_argument("--device", default=None, help="cuda or cpu (default: cuda when available)")
    tr.add_argument("--workers", type=int, default=0, help="data-loading worker processes")
    tr.add_argument("--max-side", type=int, default=1024, help="downscale photos to this before cropping")
    tr.set_defaults(run=_run_train)

    syn = sub.add_parser(
        "make-synthetic-faces",
        help="render random model instances with known parameters (training and test data for the regressor)",
        description="Random identity, expression, skin albedo, SH lighting, pose and background, rendered with the "
        "project's renderer; writes NNNNNN.png and faces.npz (parameters, 88 landmarks, cameras).",
    )
    syn.add_argument("--out", type=Path, required=True, help="output folder (created)")
    syn.add_argument("--count", type=int, default=1000, help="number of images")
    syn.add_argument("--size", type=int, default=256, help="image side in pixels")
    syn.add_argument("--max-yaw", type=float, default=75.0, help="yaw is uniform in ±this (degrees)")
    syn.add_argument("--seed", type=int, default=0, help="random seed")
    syn.add_argument("--model", type=Path, default=None, help="model file (see 'facegeo fit --help')")
    syn.set_defaults(run=_run_synthetic)


def _run_train(args: argparse.Namespace) -> None:
    from facegeo.errors import InputError
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
    config.check("<command line>")
    if args.max_steps is not None and args.max_steps < 1:
        raise InputError("<command line>", "--max-steps", "a positive number", str(args.max_steps))
    summary = train(args.images, args.out, config, model=args.model, landmarks=args.landmarks, resume=not args.no_resume,
                    device=args.device, workers=args.workers, max_side=args.max_side, max_steps=args.max_steps,
                    progress=sys.stderr.isatty())
    if summary["skipped"]:
        print(f"skipped {len(summary['skipped'])} images (listed in {args.out}/skipped.txt)")
    print(f"trained {summary['steps']} steps, {summary['epochs']} epochs on {summary['n_train']} images "
          f"({summary['n_val']} validation): train {json.dumps(summary['train'])}, validation {json.dumps(summary['val'])}")
    print(f"wrote {args.out}/last.pt, best.pt, metrics.csv")


def _run_synthetic(args: argparse.Namespace) -> None:
    from facegeo.errors import InputError
    from facegeo.model_files import load_model
    from facegeo.regressor.synthetic import make_synthetic_faces

    if args.count < 1 or not 32 <= args.size <= 4096:
        raise InputError("<command line>", "--count/--size", "count >= 1 and 32 <= size <= 4096", f"{args.count}, {args.size}")
    make_synthetic_faces(args.out, args.count, load_model(args.model), args.size, args.seed, args.max_yaw,
                         progress=sys.stderr.isatty())
    print(f"wrote {args.count} faces and faces.npz to {args.out}")
