"""The DiT, its VAE and task LoRAs: the pieces every stage of the diffusion backend shares.

Thin over diffusers (``LongCatImageTransformer2DModel``, ``AutoencoderKL``,
``FlowMatchEulerDiscreteScheduler``) and peft (named LoRA adapters on one frozen backbone).

Latents. Images (B, 3, H, W) in [0, 1] go to the VAE as 2·x − 1; latents are normalised
``(z − shift) · scale`` (LongCat's Flux VAE: 16 channels, scale 0.3611, shift 0.1159) and packed
2 × 2 into tokens (B, H/(2f)·W/(2f), 4·C) with f the VAE's downscale factor, as the LongCat
pipelines do. Conditioning is LongCat-Image-Edit's: the condition image's tokens follow the
noisy tokens along the token axis with RoPE modality id 2 (noisy tokens: id 1, text: id 0).

Time. ``sigma`` in [0, 1] is the flow-matching noise level, z_σ = (1 − σ)·z₀ + σ·ε; the model
predicts the velocity ε − z₀ and takes ``timestep = sigma`` (it multiplies by 1000 itself).

LoRA targets (the paper's appendix): ``to_q``, ``to_k``, ``to_v``, ``to_out.0``, ``add_q_proj``,
``add_k_proj``, ``add_v_proj``, ``to_add_out``, ``ff.net.0.proj``, ``ff.net.2``,
``ff_context.net.0.proj``, ``ff_context.net.2``, matched as peft matches names (by suffix). The
single-stream blocks' attention has ``to_q/k/v`` too, so they get adapters as well. Deliberate:
at rank 32 on the real LongCat sizes that gives 89.7 M parameters per adapter, the paper's
"approximately 91 M"; restricting to the dual-stream blocks would give 67.2 M
(benchmarks/RESULTS.md, ``bench_diffusion.py --sizes``).

:data:`ADALN_TARGETS` (the AdaLN modulation layers) are not the paper's and not a default: the
tests and benchmarks add them on *randomly initialised* backbones, whose frozen modulation gates
every block's residual write by random per-channel factors of about 0.1 that hardly change with
σ; a pre-trained backbone's modulation is learnt (benchmarks/RESULTS.md, "Training bar").
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import torch
from diffusers import AutoencoderKL, LongCatImageTransformer2DModel
from diffusers.pipelines.longcat_image.pipeline_longcat_image import prepare_pos_ids
from peft import LoraConfig
from peft.tuners.lora import LoraLayer

__all__ = [
    "TASKS",
    "MATERIAL_BRANCHES",
    "LORA_TARGETS",
    "ADALN_TARGETS",
    "LORA_RANK",
    "TINY_TRANSFORMER_CONFIG",
    "TINY_VAE_CONFIG",
    "lora_config",
    "add_adapters",
    "mixed_adapters",
    "lora_parameters",
    "vae_factor",
    "encode",
    "decode",
    "pack",
    "unpack",
    "velocity",
]

#: The five adapters: two texture stages and the three material branches.
TASKS = ("inpaint", "homogenise", "albedo", "normal", "rsd")
#: The material branches, in the order they are stacked along the batch axis.
MATERIAL_BRANCHES = ("albedo", "normal", "rsd")
#: The paper's LoRA target layers (appendix "Details of LoRA Injected Layers").
LORA_TARGETS = (
    "to_q", "to_k", "to_v", "to_out.0",
    "add_q_proj", "add_k_proj", "add_v_proj", "to_add_out",
    "ff.net.0.proj", "ff.net.2", "ff_context.net.0.proj", "ff_context.net.2",
)  # fmt: skip
#: The AdaLN modulation layers (σ-dependent shift, scale and gate) of the dual-stream, single-stream
#: and output blocks: extra targets for random test backbones only (module docstring).
ADALN_TARGETS = ("norm1.linear", "norm1_context.linear", "norm.linear", "norm_out.linear")
#: The paper's LoRA rank.
LORA_RANK = 32

#: A one-layer LongCat transformer for tests and benchmarks (builds in milliseconds); its 16 input
#: channels are 2 × 2-packed latents of :data:`TINY_VAE_CONFIG` (4 channels).
TINY_TRANSFORMER_CONFIG: dict[str, Any] = dict(
    patch_size=1, in_channels=16, num_layers=1, num_single_layers=1, attention_head_dim=16,
    num_attention_heads=2, joint_attention_dim=32, pooled_projection_dim=32, axes_dims_rope=[4, 6, 6],
)  # fmt: skip
#: A tiny AutoencoderKL (downscale factor 2, 4 latent channels) for tests and benchmarks.
TINY_VAE_CONFIG: dict[str, Any] = dict(
    in_channels=3, out_channels=3, down_block_types=["DownEncoderBlock2D"] * 2,
    up_block_types=["UpDecoderBlock2D"] * 2, block_out_channels=[8, 16], layers_per_block=1,
    latent_channels=4, norm_num_groups=4, sample_size=32,
)  # fmt: skip


def lora_config(rank: int = LORA_RANK, targets: Sequence[str] = LORA_TARGETS) -> LoraConfig:
    """The task adapters' peft config: ``rank`` on ``targets`` (default: the paper's
    :data:`LORA_TARGETS`), alpha = rank (scale 1), B initialised to 0 (a new adapter leaves the
    backbone's output unchanged)."""
    return LoraConfig(r=rank, lora_alpha=rank, target_modules=list(targets), init_lora_weights=True)


def add_adapters(transformer: LongCatImageTransformer2DModel, names: Sequence[str], rank: int = LORA_RANK,
                 targets: Sequence[str] = LORA_TARGETS) -> None:
    """Add one LoRA adapter per name on ``targets``; afterwards only these adapters' weights
    require gradients (the backbone and any other adapter are frozen)."""
    for name in names:
        with warnings.catch_warnings():  # peft warns on every adapter after the first; several are the point here
            warnings.filterwarnings("ignore", message="Already found a `peft_config` attribute")
            transformer.add_adapter(lora_config(rank, targets), adapter_name=name)
    transformer.requires_grad_(False)
    for p in lora_parameters(transformer, names):
        p.requires_grad_(True)


def lora_parameters(transformer: torch.nn.Module, names: Sequence[str]) -> list[torch.nn.Parameter]:
    """The LoRA A/B weights of the adapters ``names``."""
    return [p for n, p in transformer.named_parameters() if "lora_" in n and any(f".{a}." in n for a in names)]


@contextmanager
def mixed_adapters(transformer: torch.nn.Module, per_item: Sequence[str]) -> Iterator[None]:
    """Within the block, batch item i of every forward uses adapter ``per_item[i]`` (peft's
    mixed-adapter batches; ``"__base__"`` = no adapter). The batch must have ``len(per_item)``
    items. peft exposes this only through ``PeftModel.generate``/``forward`` (inference); here
    the same per-layer ``adapter_names`` argument is injected with pre-hooks, which also works
    under autograd (each LoRA sees only its own sub-batch)."""
    names = list(per_item)

    def hook(module: torch.nn.Module, args: tuple, kwargs: dict) -> tuple[tuple, dict]:
        return args, {**kwargs, "adapter_names": names}

    handles = [m.register_forward_pre_hook(hook, with_kwargs=True) for m in transformer.modules() if isinstance(m, LoraLayer)]
    try:
        yield
    finally:
        for h in handles:
            h.remove()


def vae_factor(vae: AutoencoderKL) -> int:
    """The VAE's spatial downscale factor (8 for LongCat's)."""
    return 2 ** (len(vae.config.block_out_channels) - 1)


def _shift_scale(vae: AutoencoderKL) -> tuple[float, float]:
    shift = vae.config.shift_factor
    return (0.0 if shift is None else float(shift)), float(vae.config.scaling_factor)


def encode(vae: AutoencoderKL, images: torch.Tensor) -> torch.Tensor:
    """(B, 3, H, W) images in [0, 1] -> (B, C, H/f, W/f) normalised latents (the mode of the
    posterior, as LongCat's edit pipeline takes it)."""
    shift, scale = _shift_scale(vae)
    z = vae.encode(images.to(vae.dtype) * 2.0 - 1.0).latent_dist.mode()
    return (z - shift) * scale


def decode(vae: AutoencoderKL, latents: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`encode`: (B, C, h, w) -> (B, 3, f·h, f·w) images, [0, 1] up to the VAE's
    overshoot (not clamped, so gradients pass everywhere)."""
    shift, scale = _shift_scale(vae)
    return (vae.decode(latents.to(vae.dtype) / scale + shift).sample + 1.0) * 0.5


def pack(latents: torch.Tensor) -> torch.Tensor:
    """(B, C, h, w) -> (B, h/2 · w/2, 4C) tokens (2 × 2 patches, LongCat's layout)."""
    b, c, h, w = latents.shape
    return latents.view(b, c, h // 2, 2, w // 2, 2).permute(0, 2, 4, 1, 3, 5).reshape(b, (h // 2) * (w // 2), 4 * c)


def unpack(tokens: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """Inverse of :func:`pack` for latents of size h × w."""
    b, _, d = tokens.shape
    return tokens.view(b, h // 2, w // 2, d // 4, 2, 2).permute(0, 3, 1, 4, 2, 5).reshape(b, d // 4, h, w)


def velocity(
    transformer: LongCatImageTransformer2DModel,
    noisy: torch.Tensor,
    condition: torch.Tensor,
    prompt: torch.Tensor,
    sigma: torch.Tensor,
    grid: tuple[int, int],
) -> torch.Tensor:
    """The predicted velocity v̂ = f(z_σ, condition, σ, text).

    Args:
        noisy: (B, N, D) packed z_σ. condition: (B, N, D) packed condition latents.
        prompt: (B, L, joint_attention_dim) text embeddings.
        sigma: (B,) noise levels in [0, 1].
        grid: (h/2, w/2), the token grid (N = h/2 · w/2).
    Returns:
        (B, N, D) velocity, dtype of ``noisy``.
    """
    n_text = prompt.shape[1]
    start = (n_text, n_text)
    txt_ids = prepare_pos_ids(modality_id=0, type="text", start=(0, 0), num_token=n_text)
    img_ids = prepare_pos_ids(modality_id=1, type="image", start=start, height=grid[0], width=grid[1])
    cond_ids = prepare_pos_ids(modality_id=2, type="image", start=start, height=grid[0], width=grid[1])
    device = noisy.device
    out = transformer(
        hidden_states=torch.cat([noisy, condition], dim=1),
        encoder_hidden_states=prompt,
        timestep=sigma.to(noisy.dtype),
        txt_ids=txt_ids.to(device),
        img_ids=torch.cat([img_ids, cond_ids], dim=0).to(device),
        return_dict=False,
    )[0]
    return out[:, : noisy.shape[1]]
