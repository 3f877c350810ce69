"""The base model from a local diffusers folder: DiT, VAE, scheduler and the text conditioning.

Layout of ``base_dir`` (what ``save_pretrained`` of each part writes, LongCat-Image-Edit's)::

    transformer/config.json, transformer/*.safetensors
    vae/config.json, vae/*.safetensors
    scheduler/scheduler_config.json              (optional: diffusers' defaults)
    prompt_embeds.safetensors                    precomputed caption embeddings, and/or
    text_encoder/, tokenizer/, text_processor/   the Qwen2.5-VL encoder (needed for --caption)

``prompt_embeds.safetensors`` holds one (1, L, joint_attention_dim) tensor per task of
:data:`~facegeo.texturing.diffusion.model.TASKS` (the fixed caption of :data:`CAPTIONS`) and
``negative`` (the empty caption, for guidance). Nothing is downloaded: every path is local.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from diffusers import AutoencoderKL, FlowMatchEulerDiscreteScheduler, LongCatImageTransformer2DModel
from safetensors.torch import load_file, save_file

from facegeo.errors import InputError
from facegeo.texturing.diffusion.model import TASKS, TINY_TRANSFORMER_CONFIG, TINY_VAE_CONFIG

__all__ = ["Components", "CAPTIONS", "PROMPT_FILE", "missing_base_files", "load_components", "tiny_components", "save_components"]

#: The fixed caption of each task; a user caption is appended to it.
CAPTIONS = {
    "inpaint": "Complete the missing regions of this UV face texture.",
    "homogenise": "Relight this UV face texture under uniform white light.",
    "albedo": "Estimate the diffuse albedo map of this UV face texture.",
    "normal": "Estimate the tangent-space normal map of this UV face texture.",
    "rsd": "Estimate the roughness, specular and displacement maps of this UV face texture.",
}
PROMPT_FILE = "prompt_embeds.safetensors"


def missing_base_files(base_dir: str | os.PathLike[str]) -> list[str]:
    """Every file of the base layout (module docstring) that ``base_dir`` lacks."""
    root = Path(base_dir)
    missing = [str(root / part / "config.json") for part in ("transformer", "vae") if not (root / part / "config.json").is_file()]
    missing += [str(root / part / "*.safetensors") for part in ("transformer", "vae") if not list((root / part).glob("*.safetensors"))]
    has_encoder = (root / "text_encoder" / "config.json").is_file() and (root / "tokenizer").is_dir()
    if not (root / PROMPT_FILE).is_file() and not has_encoder:
        missing.append(f"{root / PROMPT_FILE} (or text_encoder/ and tokenizer/)")
    return missing


@dataclass(eq=False)
class Components:
    """The frozen base: ``transformer``, ``vae``, ``scheduler``, the precomputed caption
    embeddings ``prompts`` (task -> (1, L, E)) and, if present, the text-encoder folder."""

    transformer: LongCatImageTransformer2DModel
    vae: AutoencoderKL
    scheduler: FlowMatchEulerDiscreteScheduler
    prompts: dict[str, torch.Tensor] = field(default_factory=dict)
    base_dir: Path | None = None
    _pipeline: object | None = field(default=None, repr=False)

    @property
    def device(self) -> torch.device:
        return next(self.transformer.parameters()).device

    @property
    def dtype(self) -> torch.dtype:
        return next(self.transformer.parameters()).dtype

    def prompt(self, task: str, caption: str | None = None, image: np.ndarray | None = None) -> torch.Tensor:
        """(1, L, E) embedding of the task's fixed caption (+ ``caption``). Without a caption the
        precomputed embedding is used when there is one; otherwise the Qwen2.5-VL encoder encodes
        the text with ``image`` ((H, W, 3) in [0, 1], the condition image) as LongCat-Image-Edit
        does. ``task="negative"`` is the empty caption."""
        if caption is None and task in self.prompts:
            return self.prompts[task].to(self.device, self.dtype)
        text = "" if task == "negative" else " ".join(filter(None, [CAPTIONS[task], caption]))
        return self._encode(text, image)

    def _encode(self, text: str, image: np.ndarray | None) -> torch.Tensor:
        root = self.base_dir
        if root is None or not (root / "text_encoder" / "config.json").is_file():
            raise InputError(root or "<components>", "text_encoder", "the Qwen2.5-VL text encoder (a caption needs it)", "none")
        if self._pipeline is None:
            from diffusers import LongCatImageEditPipeline

            self._pipeline = LongCatImageEditPipeline.from_pretrained(root, transformer=None, vae=None, torch_dtype=self.dtype).to(self.device)
        from PIL import Image

        pil = Image.fromarray((np.clip(image if image is not None else np.zeros((64, 64, 3)), 0, 1) * 255).astype(np.uint8))
        embeds, _ = self._pipeline.encode_prompt(prompt=[text], image=pil.resize((pil.width // 2, pil.height // 2)))
        return embeds.to(self.device, self.dtype)


def load_components(base_dir: str | os.PathLike[str], device: str | torch.device | None = None,
                    dtype: torch.dtype | None = None) -> Components:
    """Load the base from ``base_dir`` (module docstring) onto ``device`` (default: CUDA if
    available) in ``dtype`` (default: bfloat16 on CUDA, float32 on the CPU).

    Raises:
        InputError: naming every missing file.
    """
    root = Path(base_dir)
    missing = missing_base_files(root)
    if missing:
        raise InputError(root, "base model", "a local LongCat-Image-Edit diffusers folder", "missing " + ", ".join(missing))
    device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    dtype = dtype or (torch.bfloat16 if device.type == "cuda" else torch.float32)
    transformer = LongCatImageTransformer2DModel.from_pretrained(root / "transformer", torch_dtype=dtype).to(device)
    vae = AutoencoderKL.from_pretrained(root / "vae", torch_dtype=dtype).to(device)
    sched_dir = root / "scheduler"
    scheduler = FlowMatchEulerDiscreteScheduler.from_pretrained(sched_dir) if (sched_dir / "scheduler_config.json").is_file() else FlowMatchEulerDiscreteScheduler()
    prompts = load_file(str(root / PROMPT_FILE)) if (root / PROMPT_FILE).is_file() else {}
    transformer.requires_grad_(False)
    vae.requires_grad_(False)
    return Components(transformer.eval(), vae.eval(), scheduler, prompts, root)


def tiny_components(seed: int = 0, text_tokens: int = 8, **transformer: Any) -> Components:
    """Randomly initialised tiny components (:data:`TINY_TRANSFORMER_CONFIG` updated with
    ``transformer``, :data:`TINY_VAE_CONFIG` with the latent shift and scale of random images,
    random caption embeddings) for tests and benchmarks."""
    torch.manual_seed(seed)
    config = {**TINY_TRANSFORMER_CONFIG, **transformer}
    dit = LongCatImageTransformer2DModel(**config).eval().requires_grad_(False)
    vae = AutoencoderKL(**TINY_VAE_CONFIG).eval().requires_grad_(False)
    with torch.no_grad():  # shift and scale give unit-variance latents, as a real VAE's are chosen
        z = vae.encode(torch.rand(4, 3, 32, 32) * 2 - 1).latent_dist.mode()
    vae.register_to_config(shift_factor=float(z.mean()), scaling_factor=float(1.0 / z.std()))
    prompts = {name: torch.randn(1, text_tokens, config["joint_attention_dim"]) for name in (*TASKS, "negative")}
    return Components(dit, vae, FlowMatchEulerDiscreteScheduler(), prompts)


def save_components(components: Components, base_dir: str | os.PathLike[str]) -> Path:
    """Write ``components`` in the base layout (module docstring). Returns the folder."""
    root = Path(base_dir)
    components.transformer.save_pretrained(root / "transformer")
    components.vae.save_pretrained(root / "vae")
    components.scheduler.save_pretrained(root / "scheduler")
    save_file({k: v.contiguous() for k, v in components.prompts.items()}, str(root / PROMPT_FILE))
    return root
