"""Diffusion texture stack: sizes of the real LongCat model (meta device, no weights), CPU time of
one dual-stream block at 1K-texture token counts, the training bar on a tiny model (the loss on a
fixed σ grid before and after, beside its Bayes floor), and sampling steps against time and PSNR
on the tiny trained LoRA.

    python benchmarks/bench_diffusion.py --sizes
    python benchmarks/bench_diffusion.py --block [--tokens 8192 --text 256 --repeat 2 --branches]
    python benchmarks/bench_diffusion.py --training [--train-steps 300 --seeds 3]
    python benchmarks/bench_diffusion.py --steps [--train-steps 300]

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


def _tiny_pairs(folder: str) -> dict[str, np.ndarray]:
    """The training test's data: 2 texture pairs of 16² from one procedural PBR set."""
    from pathlib import Path

    from facegeo.cli import main as facegeo_main
    from facegeo.texturing.diffusion.data import procedural_pbr_set, read_samples, write_pbr_set

    root = Path(folder)
    write_pbr_set(root / "sets" / "skin_a", procedural_pbr_set(64, np.random.default_rng(1)))
    assert facegeo_main(["make-texture-pairs", str(root / "sets" / "skin_a"), "--procedural", "1", "--samples", "2",
                         "--size", "16", "--image-size", "96", "-o", str(root / "out")]) == 0
    return {k: v[:2] for k, v in read_samples(root / "out", ("t_inc", "t_env")).items()}


def _sample_psnr(c, lat, steps: int = 8, guidance: float = 1.0, seed: int = 0) -> float:
    """PSNR (dB) of the inpaint adapter's samples of both pairs against the targets as the (untrained,
    tiny) VAE reproduces them."""
    from facegeo.texturing.diffusion.model import decode, unpack
    from facegeo.texturing.diffusion.sampling import sample

    n = lat.condition.shape[0]
    z = sample(c.transformer, c.scheduler, lat.condition, c.prompt("inpaint").expand(n, -1, -1), c.prompt("negative").expand(n, -1, -1),
               lat.grid, adapters=["inpaint"] * n, steps=steps, guidance=guidance, generator=torch.Generator().manual_seed(seed))
    with torch.no_grad():
        out = decode(c.vae, unpack(z, *lat.latent_hw)).clamp(0, 1)
        reference = decode(c.vae, unpack(lat.targets[0], *lat.latent_hw)).clamp(0, 1)
    return float(10 * torch.log10(1 / ((out - reference) ** 2).mean()))


def _train_tiny(data: dict[str, np.ndarray], extra: tuple[str, ...], steps: int, caption_dropout: float = 0.0, seed: int = 0):
    """The training test's run: one-layer tiny backbone, inpaint LoRA rank 32 on the paper's targets
    + ``extra``, batch 8, lr 5e-3 (``caption_dropout`` 0 and ``seed`` 0 as in the test; ``seed``
    draws the backbone and the training batches). Returns (components,
    latents, validation loss per σ before, after, sample PSNR before, after, training seconds)."""
    from facegeo.texturing.diffusion.components import tiny_components
    from facegeo.texturing.diffusion.model import LORA_TARGETS, add_adapters
    from facegeo.texturing.diffusion.training import TrainConfig, encode_samples, train_lora, validation_loss

    c = tiny_components(seed)
    lat = encode_samples(c, data, "inpaint")
    add_adapters(c.transformer, ["inpaint"], targets=LORA_TARGETS + extra)
    before, psnr_before = validation_loss(c, lat, "inpaint"), _sample_psnr(c, lat)
    t = time.perf_counter()
    with tempfile.TemporaryDirectory() as run:
        train_lora(c, lat, TrainConfig(task="inpaint", steps=steps, batch=8, lr=5e-3, seed=seed, save_every=10**6,
                                       caption_dropout=caption_dropout),
                   run, progress=False)
    seconds = time.perf_counter() - t
    return c, lat, before, validation_loss(c, lat, "inpaint"), psnr_before, _sample_psnr(c, lat), seconds


def mixture_floor(lat, task: str = "inpaint") -> torch.Tensor:
    """Per-σ Bayes-optimal L_diff on :func:`validation_draws` for a predictor that ignores the
    condition: E[ε − z₀ | z_σ, σ] = (z_σ − E[z₀ | z_σ, σ])/σ with the posterior over the n targets
    ∝ exp(−‖z_σ − (1 − σ)·z₀ᵢ‖² / (2σ²)). (With the condition the floor is 0: distinct conditions
    name their target.)"""
    from facegeo.texturing.diffusion.training import validation_draws

    index, sigmas, noise = validation_draws(lat, task)
    z0 = lat.targets[0].double()
    target = z0[index]
    floors = []
    for sigma, eps in zip(sigmas.double(), noise.double()):
        z_sigma = (1 - sigma) * target + sigma * eps
        d2 = ((z_sigma[:, None] - (1 - sigma) * z0[None]) ** 2).sum((2, 3))  # (r·n, n)
        posterior = torch.softmax(-d2 / (2 * sigma**2), dim=1)
        z0_mean = torch.einsum("ij,jnd->ind", posterior, z0)
        floors.append((((z_sigma - z0_mean) / sigma - (eps - target)) ** 2).mean())
    return torch.stack(floors)


@torch.no_grad()
def modulation_stats() -> None:
    """How the frozen random backbone's AdaLN modulation depends on σ: its rms, the rms of its
    change between σ = 0.1 and 0.9, and the mean |gate| on the dual-stream block's residual writes."""
    import torch.nn.functional as F

    from facegeo.texturing.diffusion.components import tiny_components

    t = tiny_components().transformer

    def modulation(sigma: float) -> torch.Tensor:
        act = F.silu(t.time_embed(torch.tensor([1000.0 * sigma]), torch.float32))
        return torch.cat([t.transformer_blocks[0].norm1.linear(act), t.transformer_blocks[0].norm1_context.linear(act),
                          t.single_transformer_blocks[0].norm.linear(act), t.norm_out.linear(act)], dim=1)

    low, high = modulation(0.1), modulation(0.9)
    gates = low[0, :192].view(6, 32)[[2, 5]]  # gate_msa, gate_mlp of the image stream
    print(f"random one-layer backbone: AdaLN modulation rms {float(low.pow(2).mean().sqrt()):.3f}, its change from σ 0.1 to 0.9 "
          f"rms {float((high - low).pow(2).mean().sqrt()):.3f}; mean |gate| of the image stream's attention/FF writes "
          f"{float(gates.abs().mean()):.3f}")


def training(steps: int, seeds: int) -> None:
    from facegeo.texturing.diffusion.model import ADALN_TARGETS
    from facegeo.texturing.diffusion.training import validation_sigmas

    modulation_stats()
    with tempfile.TemporaryDirectory() as folder:
        data = _tiny_pairs(folder)
    variants = (("paper's targets", ()), ("+ norm_out", ADALN_TARGETS[3:]), ("+ block modulation", ADALN_TARGETS[:3]),
                ("+ all AdaLN", ADALN_TARGETS))
    runs = {name: _train_tiny(data, extra, steps) for name, extra in variants}
    lat = next(iter(runs.values()))[1]
    assert not torch.equal(lat.condition[0], lat.condition[1])  # distinct conditions: the conditional floor is 0
    floor = mixture_floor(lat)
    print(f"inpaint LoRA, rank 32, {steps} steps of batch 8, lr 5e-3, one-layer tiny backbone, 2 pairs of 16²; "
          f"L_diff on the fixed σ grid (16 mid-quantiles of the logit-normal, 2 noise draws per pair)")
    print("sigma  floor(no cond)  untrained  " + "  ".join(f"{name:>18s}" for name in runs))
    before = next(iter(runs.values()))[2]
    for k, sigma in enumerate(validation_sigmas()):
        print(f"{float(sigma):5.3f}  {float(floor[k]):14.4f}  {float(before[k]):9.3f}  "
              + "  ".join(f"{float(r[3][k]):18.3f}" for r in runs.values()))
    print(f"mean   {float(floor.mean()):14.4f}  {float(before.mean()):9.3f}  " + "  ".join(f"{float(r[3].mean()):18.3f}" for r in runs.values()))
    for name, (_, _, b, a, pb, pa, seconds) in runs.items():
        print(f"{name}: loss {float(b.mean()):.3f} -> {float(a.mean()):.3f} ({float(b.mean() / a.mean()):.2f}x; minus the floor 0: same), "
              f"sample PSNR {pb:.2f} -> {pa:.2f} dB (8 steps, guidance 1), training {seconds:.1f} s")
    for seed in range(1, seeds):  # the test's configuration on other random backbones and batch draws
        _, _, b, a, pb, pa, _ = _train_tiny(data, ADALN_TARGETS, steps, seed=seed)
        print(f"+ all AdaLN, seed {seed}: loss {float(b.mean()):.3f} -> {float(a.mean()):.3f} ({float(b.mean() / a.mean()):.2f}x), "
              f"lower at every σ: {bool((a < b).all())}, sample PSNR {pb:.2f} -> {pa:.2f} dB")


def steps_vs_psnr(train_steps: int) -> None:
    with tempfile.TemporaryDirectory() as folder:
        data = _tiny_pairs(folder)
    from facegeo.texturing.diffusion.model import ADALN_TARGETS

    c, lat, before, after, *_ = _train_tiny(data, ADALN_TARGETS, train_steps, caption_dropout=0.1)  # dropout: guidance needs it
    print(f"inpaint LoRA (paper's targets + AdaLN modulation, rank 32, {train_steps} steps, caption dropout 0.1, one-layer tiny "
          f"backbone, 2 pairs of 16²): validation loss {float(before.mean()):.3f} -> {float(after.mean()):.3f}")
    print("steps  guidance  seconds  PSNR dB (vs the VAE-decoded targets)")
    for guidance in (1.0, 2.0):
        for steps in (1, 2, 4, 8, 16, 30):
            times, psnrs = [], []
            for seed in range(3):
                t = time.perf_counter()
                psnrs.append(_sample_psnr(c, lat, steps, guidance, seed))
                times.append(time.perf_counter() - t)
            print(f"{steps:5d}  {guidance:8.1f}  {min(times):7.3f}  {np.mean(psnrs):6.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", action="store_true")
    parser.add_argument("--block", action="store_true")
    parser.add_argument("--steps", action="store_true")
    parser.add_argument("--training", action="store_true", help="the training bar: per-σ loss before/after, its floor")
    parser.add_argument("--tokens", type=int, default=8192)
    parser.add_argument("--text", type=int, default=256)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--branches", action="store_true", help="--block: also time the three-branch cross-intrinsic block")
    parser.add_argument("--train-steps", type=int, default=300)
    parser.add_argument("--seeds", type=int, default=1, help="--training: also run the test's configuration on other random backbones")
    args = parser.parse_args()
    if args.sizes:
        sizes()
    if args.block:
        block_time(args.tokens, args.text, args.repeat, args.branches)
    if args.training:
        training(args.train_steps, args.seeds)
    if args.steps:
        steps_vs_psnr(args.train_steps)


if __name__ == "__main__":
    main()
