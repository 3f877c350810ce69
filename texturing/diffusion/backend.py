"""``DiffusionBackend``: the paper's texture stages behind the ``TextureBackend`` protocol.

One frozen LongCat-Image-Edit DiT with five LoRA adapters (inpaint, homogenise and the material
branches albedo, normal, rsd), sampled with flow matching (30 steps, guidance 2.0 by default),
then Real-ESRGAN ×4. Shapes and encodings are :class:`~facegeo.texturing.DefaultBackend`'s: S × S
maps, colour sRGB in [0, 1], float32. The DiT runs at ``resolution`` texels (the paper's 1K);
maps of another size are resized in and out (area down, Lanczos up).

``rsd`` branch: its RGB image is unpacked as R = roughness [0, 1], G = specular [0, 1],
B = displacement, 0..1 ↔ −1..+1 mm (:func:`~facegeo.texturing.diffusion.data.unpack_rsd`).

Weights folder of :meth:`DiffusionBackend.from_weights` (``facegeo reconstruct --backend
diffusion --weights DIR``)::

    DIR/base/                         the base (facegeo.texturing.diffusion.components)
    DIR/loras/<task>/pytorch_lora_weights.safetensors   for inpaint, homogenise, albedo, normal, rsd
    DIR/sr/RealESRGAN_x4plus.pth      the super-resolution network
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np
import torch

from facegeo.asset import MAP_NAMES
from facegeo.errors import InputError
from facegeo.texturing.backend import SKIN_CONSTANTS, TextureContext
from facegeo.texturing.diffusion.components import PROMPT_FILE, Components, load_components, missing_base_files
from facegeo.texturing.diffusion.data import unpack_rsd
from facegeo.texturing.diffusion.model import MATERIAL_BRANCHES, TASKS, decode, encode, pack, unpack, vae_factor
from facegeo.texturing.diffusion.sampling import DEFAULT_GUIDANCE, DEFAULT_STEPS, sample
from facegeo.texturing.diffusion.sr import RRDBNet, load_realesrgan, upscale_tiled
from facegeo.texturing.image_filters import pad_outside

__all__ = ["DiffusionBackend", "LORA_FILE", "SR_FILE", "missing_weight_files"]

LORA_FILE = "pytorch_lora_weights.safetensors"
SR_FILE = "RealESRGAN_x4plus.pth"
#: The maps each material branch produces.
_BRANCH_MAPS = {"albedo": ("albedo",), "normal": ("normal",), "rsd": ("roughness", "specular", "displacement")}


def missing_weight_files(base_dir: str | os.PathLike[str], loras: dict[str, str | os.PathLike[str]], sr: str | os.PathLike[str] | None) -> list[str]:
    """Every file :meth:`DiffusionBackend.from_pretrained` would need and cannot find."""
    missing = missing_base_files(base_dir)
    for task in TASKS:
        if task not in loras:
            missing.append(f"<lora {task}>")
        elif not (Path(loras[task]) / LORA_FILE).is_file():
            missing.append(str(Path(loras[task]) / LORA_FILE))
    if sr is not None and not Path(sr).is_file():
        missing.append(str(sr))
    return missing


def _resize(image: np.ndarray, size: int) -> np.ndarray:
    if image.shape[0] == size:
        return image
    mode = cv2.INTER_AREA if image.shape[0] > size else cv2.INTER_LANCZOS4
    return cv2.resize(image, (size, size), interpolation=mode)


@dataclass(eq=False)
class DiffusionBackend:
    """The diffusion texture backend (module docstring). ``captions``: optional task -> extra
    caption (needs the text encoder). ``report`` holds the settings and timings of the last calls;
    ``constants`` (:data:`~facegeo.texturing.backend.SKIN_CONSTANTS`) the maps not asked for."""

    constants: ClassVar[Mapping[str, float]] = SKIN_CONSTANTS
    components: Components
    sr: RRDBNet | None = None
    steps: int = DEFAULT_STEPS
    guidance: float = DEFAULT_GUIDANCE
    resolution: int = 1024
    seed: int = 0
    captions: dict[str, str] = field(default_factory=dict)
    name: str = "diffusion"
    report: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_pretrained(cls, base_dir: str | os.PathLike[str], loras: dict[str, str | os.PathLike[str]],
                        sr: str | os.PathLike[str] | None = None, *, device: str | None = None, **options: Any) -> DiffusionBackend:
        """Load the base, the five adapters (``loras``: task -> folder of ``save_lora_adapter``)
        and the Real-ESRGAN checkpoint ``sr`` (None: Lanczos upscaling). Every path is local.

        Raises:
            InputError: naming every missing file, before anything is loaded.
        """
        missing = missing_weight_files(base_dir, loras, sr)
        if missing:
            raise InputError(base_dir, "diffusion weights", "the base model, five LoRAs and the SR network", "missing " + ", ".join(missing))
        components = load_components(base_dir, device=device)
        for task in TASKS:
            components.transformer.load_lora_adapter(str(loras[task]), weight_name=LORA_FILE, use_safetensors=True,
                                                    adapter_name=task, prefix=None)
        net = load_realesrgan(sr).to(components.device) if sr is not None else None
        return cls(components, net, **options)

    @classmethod
    def from_weights(cls, folder: str | os.PathLike[str] | None, **options: Any) -> DiffusionBackend:
        """:meth:`from_pretrained` on the weights folder layout (module docstring)."""
        if folder is None:
            raise InputError("<argument>", "--weights", "a folder with base/, loras/ and sr/ for the diffusion backend", "none")
        root = Path(folder)
        return cls.from_pretrained(root / "base", {t: root / "loras" / t for t in TASKS}, root / "sr" / SR_FILE, **options)

    # ------------------------------------------------------------------------------ the DiT
    def _generate(self, condition: np.ndarray, tasks: tuple[str, ...]) -> list[np.ndarray]:
        """Sample one image per task from one condition image (S, S, 3) in [0, 1]; several tasks
        are the material branches, sampled jointly with cross-intrinsic attention."""
        c = self.components
        start = time.perf_counter()
        size = condition.shape[0]
        res = self.resolution
        step = 2 * vae_factor(c.vae)
        if res % step:
            raise InputError("<argument>", "resolution", f"a multiple of {step}", str(res))
        image = np.clip(_resize(condition.astype(np.float32), res), 0, 1)
        x = torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1)))[None].to(c.device, c.dtype)
        with torch.no_grad():
            latent = encode(c.vae, x)
        hw = tuple(latent.shape[-2:])
        cond = pack(latent).repeat(len(tasks), 1, 1)
        prompts = [c.prompt(t, self.captions.get(t), image) for t in tasks]
        if len({p.shape[1] for p in prompts}) > 1:  # LongCat pads every caption to 512 tokens; precomputed ones must agree
            raise InputError(PROMPT_FILE, ", ".join(tasks), "caption embeddings of one length", str([p.shape[1] for p in prompts]))
        prompt = torch.cat(prompts)
        negative = c.prompt("negative").expand(len(tasks), -1, -1) if self.guidance > 1 else prompt
        generator = torch.Generator().manual_seed(self.seed)
        z = sample(c.transformer, c.scheduler, cond, prompt, negative, (hw[0] // 2, hw[1] // 2), adapters=tasks,
                   modalities=len(tasks), steps=self.steps, guidance=self.guidance, generator=generator)
        with torch.no_grad():
            out = decode(c.vae, unpack(z.to(c.dtype), *hw)).float().clamp(0, 1).cpu().numpy()
        self.report["+".join(tasks)] = {"steps": self.steps, "guidance": self.guidance, "resolution": res, "seed": self.seed,
                                        "seconds": time.perf_counter() - start}
        return [np.clip(_resize(np.ascontiguousarray(o.transpose(1, 2, 0)), size), 0.0, 1.0) for o in out]

    # ------------------------------------------------------------------------------ protocol
    def inpaint(self, T_inc: np.ndarray, M_vis: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S, 3) sRGB + (S, S) visibility -> (S, S, 3) sRGB completed texture (conditioned on
        T_inc·M_vis, as the pairs of Sec. 3.1 are)."""
        (out,) = self._generate(T_inc * np.clip(M_vis, 0, 1)[..., None], ("inpaint",))
        return pad_outside(out.astype(np.float32), ctx.coverage)

    def homogenise(self, T_full: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S, 3) sRGB -> (S, S, 3) sRGB under uniform white light."""
        (out,) = self._generate(T_full, ("homogenise",))
        return pad_outside(out.astype(np.float32), ctx.coverage)

    def materials(self, T_hom: np.ndarray, ctx: TextureContext, maps: frozenset[str] | set[str] = frozenset(MAP_NAMES)) -> dict[str, np.ndarray]:
        """PBR maps from the homogenised texture. Only the branches that produce a map in ``maps``
        run (joint attention then spans those branches only)."""
        unknown = set(maps) - set(MAP_NAMES)
        if unknown:
            raise ValueError(f"maps: expected a subset of {MAP_NAMES}, got {sorted(unknown)}")
        branches = tuple(b for b in MATERIAL_BRANCHES if set(_BRANCH_MAPS[b]) & set(maps))
        if not branches:
            return {}
        images = dict(zip(branches, self._generate(T_hom, branches)))
        found: dict[str, np.ndarray] = {}
        if "albedo" in images:
            found["albedo"] = images["albedo"]
        if "normal" in images:
            n = images["normal"] * 2.0 - 1.0
            found["normal"] = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)
        if "rsd" in images:
            found.update(unpack_rsd(images["rsd"]))
        return {k: pad_outside(v.astype(np.float32), ctx.coverage) for k, v in found.items() if k in maps}

    def upscale(self, map_: np.ndarray, factor: int) -> np.ndarray:
        """Real-ESRGAN ×4 (tiled), then area-downsampled for factor 2; Lanczos without an SR
        network. One-channel maps go through as grey RGB; maps with values outside [0, 1] (normals,
        displacement) are mapped affinely into [0, 1] by their range and back."""
        if factor == 1:
            return map_
        if factor not in (2, 4):
            raise ValueError(f"upscale factor: expected 1, 2 or 4, got {factor}")
        h, w = map_.shape[:2]
        if self.sr is None:
            return cv2.resize(map_, (w * factor, h * factor), interpolation=cv2.INTER_LANCZOS4)
        x = map_.astype(np.float32)
        x3 = np.repeat(x[..., None], 3, axis=-1) if x.ndim == 2 else x
        lo, hi = min(float(x3.min()), 0.0), max(float(x3.max()), 1.0)  # [0, 1] maps pass unchanged
        y = upscale_tiled(self.sr, (x3 - lo) / (hi - lo)) * (hi - lo) + lo
        if factor == 2:
            y = cv2.resize(y, (w * 2, h * 2), interpolation=cv2.INTER_AREA)
        return (y.mean(axis=-1) if x.ndim == 2 else y).astype(np.float32)
