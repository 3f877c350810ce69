"""Diffusion texture stack: sizes of the real LongCat model (meta device, no weights), CPU time of
one dual-stream block at 1K-texture token counts, and sampling steps against time and PSNR on a
tiny trained LoRA.

    python benchmarks/bench_diffusion.py --sizes
    python benchmarks/bench_diffusion.py --block [--tokens 8192 --text 256 --repeat 2 --branches]
    python benchmarks/bench_diffusion.py --steps [--train-steps 600]

Token count of a 1K texture: 1024² texels → VAE /8 → 128² latents → 2 × 2 packing → 4096 tokens,
and LongCat-Image-Edit appends the condition image's 4096 tokens: 8192 image tokens + text.
"""

from __future__ import annotations

import argparse
import re
import tempfile
import time

import numpy as np
import torch


def sizes() -> None:
    from diffusers import AutoencoderKL, LongCatImageTransformer2DModel

    from facegeo.texturing.diffusion.model import LORA_RANK, LORA_TARGETS

    with torch.device("meta"):
        dit = LongCatImageTransformer2DModel()  # the class defaults are LongCat-Image's sizes
        vae = AutoencoderKL(block_out_channels=[128, 256, 512, 512], latent_channels=16, layers_per_block=2,
                            down_block_types=["DownEncoderBlock2D"] * 4, up_block_types=["UpDecoderBlock2D"] * 4,
                            use_quant_conv=False, use_post_quant_conv=False)
    n_dit = sum(p.numel() for p in dit.parameters())
    n_vae = sum(p.numel() for p in vae.parameters())

    def lora(dual_only: bool) -> int:
        total = 0
        for name, m in dit.named_modules():
            if isinstance(m, torch.nn.Linear) and any(name == t or name.endswith("." + t) for t in LORA_TARGETS):
                if dual_only and not re.match(r"transformer_blocks\.\d+\.", name):
                    continue
                total += LORA_RANK * (m.in_features + m.out_features)
        return total

    block = dit.transformer_blocks[0]
    n_block = sum(p.numel() for p in block.parameters())
    print(f"DiT: {n_dit / 1e9:.3f} B parameters = {n_dit * 2 / 2**30:.1f} GiB in bfloat16 ({n_dit * 4 / 2**30:.1f} GiB float32)")
    print(f"  {len(dit.transformer_blocks)} dual-stream blocks of {n_block / 1e6:.1f} M, {len(dit.single_transformer_blocks)} single-stream blocks")
    print(f"VAE (Flux layout): {n_vae / 1e6:.1f} M parameters")
    print(f"LoRA rank {LORA_RANK}, paper's targets by suffix: {lora(False) / 1e6:.1f} M per adapter "
          f"({100 * lora(False) / n_dit:.2f} % of the DiT); dual-stream blocks only: {lora(True) / 1e6:.1f} M")


def block_time(tokens: int, text: int, repeat: int, branches: bool) -> None:
    from diffusers.models.transformers.transformer_longcat_image import LongCatImagePosEmbed, LongCatImageTransformerBlock

    from facegeo.texturing.diffusion.attention import CrossIntrinsicAttention

    torch.manual_seed(0)
    dim = 24 * 128
    block = LongCatImageTransformerBlock(dim=dim, num_attention_heads=24, attention_head_dim=128).eval()
    hidden = torch.randn(1, tokens, dim) * 0.1
    context = torch.randn(1, text, dim) * 0.1
    temb = torch.randn(1, dim)
    side = int(np.sqrt(tokens // 2))
    ids = torch.zeros(text + tokens, 3)
    ids[text:, 1] = torch.arange(tokens) // side % side
    ids[text:, 2] = torch.arange(tokens) % side
    rope = LongCatImagePosEmbed(10000, [16, 56, 56])(ids)
    print(f"one dual-stream block, {tokens} image + {text} text tokens, float32, {torch.get_num_threads()} threads")
    times = []
    with torch.no_grad():
        for _ in range(repeat):
            t = time.perf_counter()
            block(hidden, context, temb, rope)
            times.append(time.perf_counter() - t)
            print(f"  forward: {times[-1]:.1f} s", flush=True)
    print(f"  stock attention: min {min(times):.1f} s, median {float(np.median(times)):.1f} s over {repeat}")
    if branches:  # the material stage's batch: three branches, keys/values over all three
        block.attn.set_processor(CrossIntrinsicAttention(3))
        with torch.no_grad():
            t = time.perf_counter()
            block(hidden.repeat(3, 1, 1), context.repeat(3, 1, 1), temb.repeat(3, 1), rope)
        print(f"  three branches, cross-intrinsic attention: {time.perf_counter() - t:.1f} s")
    # a single-stream block costs about one dual-stream block: 12·d² multiply-adds per token in its linear layers
    # (q, k, v 3d², proj_mlp 4d², proj_out 5d²) against the dual block's image stream (attention 4d², FF 8d²)
    per_stage = min(times) * (19 + 38) * 30 * 2  # 57 blocks, 30 steps, guidance = two forwards per step
    print(f"  extrapolated 30-step stage with guidance (19 dual + 38 single blocks): {per_stage / 3600:.0f} h on this CPU")


def steps_vs_psnr(train_steps: int) -> None:
    import cv2

    from facegeo.texturing.diffusion.components import tiny_components
    from facegeo.texturing.diffusion.model import add_adapters, decode, unpack
    from facegeo.texturing.diffusion.sampling import sample
    from facegeo.texturing.diffusion.training import TrainConfig, encode_samples, train_lora

    torch.manual_seed(0)
    # the wider random backbone of the slow training test (the one-layer one learns too slowly)
    c = tiny_components(num_attention_heads=4, attention_head_dim=32, num_layers=2, num_single_layers=2, axes_dims_rope=[8, 12, 12])
    rng = np.random.default_rng(0)
    n, size = 2, 16
    cond = np.stack([cv2.GaussianBlur(rng.random((size, size, 3)).astype(np.float32), (0, 0), 1.5) for _ in range(n)])
    cond = (cond - cond.min()) / (cond.max() - cond.min())
    lat = encode_samples(c, {"t_inc": cond, "t_env": 1.0 - cond}, "inpaint")
    add_adapters(c.transformer, ["inpaint"], 16)
    with tempfile.TemporaryDirectory() as run:
        rows = train_lora(c, lat, TrainConfig(task="inpaint", steps=train_steps, batch=n, lr=3e-3, rank=16, save_every=10**6,
                                             caption_dropout=0.1), run, progress=False)
    first, last = np.mean([r["diff"] for r in rows[:20]]), np.mean([r["diff"] for r in rows[-20:]])
    print(f"small LoRA (inpaint, {n} pairs of {size}², {train_steps} steps, caption dropout 0.1): "
          f"training loss (mean of 20 steps) {first:.3f} -> {last:.3f}")
    with torch.no_grad():
        reference = decode(c.vae, unpack(lat.targets[0], *lat.latent_hw)).clamp(0, 1)
    print("steps  guidance  seconds  PSNR dB (vs the VAE-decoded targets)")
    for guidance in (1.0, 2.0):
        for steps in (1, 2, 4, 8, 16, 30):
            times, psnrs = [], []
            for seed in range(3):
                t = time.perf_counter()
                z = sample(c.transformer, c.scheduler, lat.condition, c.prompt("inpaint").expand(n, -1, -1),
                           c.prompt("negative").expand(n, -1, -1), lat.grid, adapters=["inpaint"] * n, steps=steps,
                           guidance=guidance, generator=torch.Generator().manual_seed(seed))
                with torch.no_grad():
                    out = decode(c.vae, unpack(z, *lat.latent_hw)).clamp(0, 1)
                times.append(time.perf_counter() - t)
                psnrs.append(float(10 * torch.log10(1 / ((out - reference) ** 2).mean())))
            print(f"{steps:5d}  {guidance:8.1f}  {min(times):7.3f}  {np.mean(psnrs):6.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", action="store_true")
    parser.add_argument("--block", action="store_true")
    parser.add_argument("--steps", action="store_true")
    parser.add_argument("--tokens", type=int, default=8192)
    parser.add_argument("--text", type=int, default=256)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--branches", action="store_true", help="--block: also time the three-branch cross-intrinsic block")
    parser.add_argument("--train-steps", type=int, default=600)
    args = parser.parse_args()
    if args.sizes:
        sizes()
    if args.block:
        block_time(args.tokens, args.text, args.repeat, args.branches)
    if args.steps:
        steps_vs_psnr(args.train_steps)


if __name__ == "__main__":
    main()
