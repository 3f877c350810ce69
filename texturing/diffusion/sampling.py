"""The flow-matching sampler: Euler steps of LongCat's scheduler with classifier-free guidance.

One call denoises a batch whose items may use different LoRA adapters (``adapters``, see
:func:`~facegeo.texturing.diffusion.model.mixed_adapters`) and, for the material branches,
cross-intrinsic attention (``modalities`` > 1).
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import ExitStack

import numpy as np
import torch
from diffusers import FlowMatchEulerDiscreteScheduler
from diffusers.pipelines.longcat_image.pipeline_longcat_image import calculate_shift

from facegeo.texturing.diffusion.attention import cross_intrinsic
from facegeo.texturing.diffusion.model import mixed_adapters, velocity

__all__ = ["sample", "DEFAULT_STEPS", "DEFAULT_GUIDANCE"]

#: The paper's inference settings (Tab. A2: 30 steps, guidance 2.0).
DEFAULT_STEPS = 30
DEFAULT_GUIDANCE = 2.0


@torch.no_grad()
def sample(
    transformer: torch.nn.Module,
    scheduler: FlowMatchEulerDiscreteScheduler,
    condition: torch.Tensor,
    prompt: torch.Tensor,
    negative: torch.Tensor,
    grid: tuple[int, int],
    *,
    adapters: Sequence[str],
    modalities: int = 1,
    steps: int = DEFAULT_STEPS,
    guidance: float = DEFAULT_GUIDANCE,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Denoise from pure noise to clean packed latents.

    Args:
        condition: (B, N, D) packed condition latents. prompt, negative: (B, L, E) text
            embeddings of the task caption and of the empty caption (used when guidance > 1).
        grid: the token grid (N = grid[0]·grid[1]).
        adapters: B adapter names, one per item. modalities: branches for cross-intrinsic
            attention (1: the stock processor).
        steps: Euler steps (σ from 1 to 1/steps, shifted as LongCat's pipeline does).
        guidance: classifier-free guidance scale; ≤ 1 runs the conditional branch only.
    Returns:
        (B, N, D) clean latents ẑ₀ (float32).
    """
    if steps < 1:
        raise ValueError(f"steps: expected ≥ 1, got {steps}")
    device, dtype = condition.device, condition.dtype
    z = torch.randn(condition.shape, generator=generator, device="cpu", dtype=torch.float32).to(device, dtype)
    sigmas = np.linspace(1.0, 1.0 / steps, steps)
    cfg = scheduler.config
    if cfg.get("use_dynamic_shifting", False):
        mu = calculate_shift(condition.shape[1], cfg.get("base_image_seq_len", 256), cfg.get("max_image_seq_len", 4096),
                             cfg.get("base_shift", 0.5), cfg.get("max_shift", 1.15))
        scheduler.set_timesteps(sigmas=sigmas, mu=mu, device=device)
    else:
        scheduler.set_timesteps(sigmas=sigmas, device=device)
    with ExitStack() as stack:
        stack.enter_context(mixed_adapters(transformer, adapters))
        if modalities > 1:
            stack.enter_context(cross_intrinsic(transformer, modalities))
        for t in scheduler.timesteps:
            sigma = (t / 1000.0).expand(z.shape[0]).to(device)
            v = velocity(transformer, z, condition, prompt, sigma, grid)
            if guidance > 1.0:
                v_neg = velocity(transformer, z, condition, negative, sigma, grid)
                v = v_neg + guidance * (v - v_neg)
            z = scheduler.step(v, t, z, return_dict=False)[0]
    return z.float()
