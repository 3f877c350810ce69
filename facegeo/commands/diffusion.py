"""The diffusion backend's subcommands: ``train-lora`` and ``make-texture-pairs``
(:mod:`facegeo.texturing.diffusion`). Parsing imports nothing heavy; the commands import
diffusers only when they run and say how to install the optional extra when it is missing."""

from __future__ import annotations

import argparse
from pathlib import Path

from facegeo.commands.arguments import COMMAND_LINE, Command, add_device_argument, add_seed_argument
from facegeo.errors import InputError

__all__ = ["COMMANDS"]


def _train_arguments(train: argparse.ArgumentParser) -> None:
    train.add_argument("--task", choices=["inpaint", "homogenise", "materials"], required=True)
    train.add_argument("--data", type=Path, required=True, help="pairs folder from 'facegeo make-texture-pairs'")
    train.add_argument("--out", type=Path, required=True, help="run folder (created; --resume continues it)")
    train.add_argument("--base", type=Path, required=True, help="local diffusers folder of the base model (transformer/, vae/, prompt_embeds.safetensors)")
    train.add_argument("--steps", type=int, default=1000)
    train.add_argument("--batch", type=int, default=4)
    train.add_argument("--lr", type=float, default=1e-4)
    train.add_argument("--rank", type=int, default=32)
    train.add_argument("--joint-steps", type=int, default=None, help="materials: steps of the joint stage (default: half)")
    train.add_argument("--lpips", type=Path, default=None, help="LPIPS checkpoint (the lpips package's VGG layout); without it the term is dropped")
    train.add_argument("--save-every", type=int, default=500)
    add_seed_argument(train)
    add_device_argument(train)
    train.add_argument("--resume", action="store_true", help="continue from the run's latest checkpoint")


def _pairs_arguments(pairs: argparse.ArgumentParser) -> None:
    pairs.add_argument("sets", type=Path, nargs="*", help="PBR set folders")
    pairs.add_argument("-o", "--output", type=Path, required=True, help="output folder (created)")
    pairs.add_argument("--procedural", type=int, default=0, help="also use this many procedurally generated skin PBR sets")
    pairs.add_argument("--samples", type=int, default=8, help="pairs per set")
    pairs.add_argument("--size", type=int, default=1024, help="UV size S of the pairs")
    pairs.add_argument("--image-size", type=int, default=1024, help="size of the rendered photo in pixels")
    pairs.add_argument("--displacement-mm", type=float, default=0.1, help="displacement of the sets' white level (0.5 grey = 0)")
    add_seed_argument(pairs)


def _run_train(args: argparse.Namespace) -> None:
    from facegeo.texturing.diffusion import require_extra

    require_extra()
    from facegeo.texturing.diffusion.components import load_components
    from facegeo.texturing.diffusion.data import read_samples
    from facegeo.texturing.diffusion.training import TASK_DATA, TrainConfig, encode_samples, train_lora

    cond, targets = TASK_DATA[args.task]
    samples = read_samples(args.data, (cond, *targets))  # the data is checked before the model loads
    components = load_components(args.base, device=args.device)
    latents = encode_samples(components, samples, args.task)
    config = TrainConfig(task=args.task, steps=args.steps, batch=args.batch, lr=args.lr, rank=args.rank, seed=args.seed,
                         save_every=args.save_every, joint_steps=args.joint_steps, lpips=str(args.lpips) if args.lpips else None)
    rows = train_lora(components, latents, config, args.out, resume=args.resume)
    if rows:
        print(f"trained {args.task} to step {int(rows[-1]['step'])}: loss {rows[0]['loss']:.4f} -> {rows[-1]['loss']:.4f}; wrote {args.out}")


def _run_pairs(args: argparse.Namespace) -> None:
    import numpy as np

    from facegeo.texturing.diffusion.data import make_texture_pairs, procedural_pbr_set, read_pbr_set

    if not args.sets and args.procedural <= 0:
        raise InputError(COMMAND_LINE, "sets", "PBR set folders or --procedural N", "none")
    sets = [(p.name, read_pbr_set(p, args.size, args.displacement_mm)) for p in args.sets]
    rng = np.random.default_rng(args.seed)
    sets += [(f"procedural{k:03d}", procedural_pbr_set(args.size, rng)) for k in range(args.procedural)]
    count = make_texture_pairs(sets, args.output, args.samples, seed=args.seed, image_size=args.image_size)
    print(f"wrote {count} texture pairs of {args.size}² to {args.output}")


COMMANDS = (
    Command(
        "train-lora",
        help="train the diffusion backend's task LoRAs on texture pairs (needs the [diffusion] extra)",
        description="Flow-matching LoRA training on a frozen LongCat-Image-Edit base (Sec. 3.3-3.4). "
        "Writes RUN/metrics.csv, RUN/checkpoint-<step>/ and one adapter folder per LoRA.",
        arguments=_train_arguments,
        run=_run_train,
    ),
    Command(
        "make-texture-pairs",
        help="render paired training data (T_inc, T_env, T_hom, T_PBR) from PBR texture sets",
        description="For each PBR set folder (albedo/normal/roughness/specular/displacement .png) render "
        "random poses and lights with facegeo's shader, renderer and unwrap (Sec. 3.1).",
        arguments=_pairs_arguments,
        run=_run_pairs,
    ),
)
