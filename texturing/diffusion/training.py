"""LoRA training with the flow-matching objective (Sec. 3.3–3.4) and the shading loss (Sec. 3.4).

Tasks and their pairs (:mod:`facegeo.texturing.diffusion.data`):

=============== ============= ================================ ======================
task            condition     target(s)                        adapters
=============== ============= ================================ ======================
``inpaint``     ``t_inc``     ``t_env``                        inpaint
``homogenise``  ``t_env``     ``t_hom``                        homogenise
``materials``   ``t_hom``     ``albedo``, ``normal``, ``rsd``  albedo, normal, rsd
=============== ============= ================================ ======================

Loss: z_σ = (1 − σ)·z₀ + σ·ε with ε ~ N(0, I) and σ logit-normal (σ = sigmoid(N(0, 1)), the
density of SD3's and Flux's trainers; the paper does not state one); L_diff = ‖v̂ − (ε − z₀)‖².
The backbone and VAE are frozen; only the LoRA weights train (AdamW, lr 1e-4, rank 32 by
default; bfloat16 autocast on CUDA, float32 on the CPU). ``materials`` follows the paper's
two-stage schedule: stage 1 trains the three branches independently (stacked in one batch, each
with its own adapter, stock attention, L_diff only); stage 2 trains them jointly with
cross-intrinsic attention and the hybrid objective
L = L_diff + λ_img·‖Ŝ − S‖² + λ_lpips·LPIPS(Ŝ, S), where ẑ₀ = z_σ − σ·v̂ is decoded into the
five maps, shaded with ``shade_ggx`` on the template geometry (the model's mean shape) under a
sampled camera and light (:class:`ShadingSupervisor`), and compared in sRGB with the target maps
shaded the same way, weighted by the visibility M·(N_g·v)⁺. LPIPS needs a local checkpoint
(:mod:`facegeo.texturing.diffusion.lpips`); without one its term is dropped with a logged note.

:func:`validation_loss` evaluates L_diff on a fixed σ grid and fixed noise, so that losses
before and after training compare the same draws (the running training loss does not).

A run folder holds ``metrics.csv`` (one row per step), ``checkpoint-<step>/state.pt`` (LoRA
weights, optimiser, step, random states; ``resume`` continues from the latest) and, at the end,
one folder per adapter written by diffusers' ``save_lora_adapter``.
"""

from __future__ import annotations

import csv
import io
import math
import os
import time
from collections.abc import Callable
from contextlib import ExitStack, nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from facegeo.texturing.diffusion.attention import cross_intrinsic
from facegeo.texturing.diffusion.components import Components
from facegeo.texturing.diffusion.data import RSD_DISPLACEMENT_MM
from facegeo.texturing.diffusion.model import (
    LORA_RANK, MATERIAL_BRANCHES, add_adapters, decode, encode, lora_parameters, mixed_adapters, pack, unpack, velocity,
)  # fmt: skip
from facegeo.colour import linear_to_srgb_torch, srgb_to_linear_torch
from facegeo.texturing.shading import shade_ggx

__all__ = [
    "TASK_DATA",
    "TASK_ADAPTERS",
    "TrainConfig",
    "LatentSet",
    "encode_samples",
    "ShadingSupervisor",
    "maps_from_images",
    "flow_matching_step",
    "validation_sigmas",
    "validation_draws",
    "validation_loss",
    "train_lora",
]

#: task -> (condition image, target images).
TASK_DATA = {"inpaint": ("t_inc", ("t_env",)), "homogenise": ("t_env", ("t_hom",)), "materials": ("t_hom", ("albedo", "normal", "rsd"))}
#: task -> adapters trained.
TASK_ADAPTERS = {"inpaint": ("inpaint",), "homogenise": ("homogenise",), "materials": MATERIAL_BRANCHES}


@dataclass
class TrainConfig:
    """Options of :func:`train_lora` (paper: lr 1e-4, rank 32, λ_img 0.5, λ_lpips 0.1; its batch
    sizes 64 and 8 and 20k steps are for 8 H100s). ``joint_steps``: the materials task's stage-2
    steps (default: half of ``steps``). ``batch``: items per step, drawn from the pairs with
    replacement (it may exceed their number; each item gets its own σ and noise).
    ``caption_dropout``: probability that an item trains with
    the empty caption instead (what classifier-free guidance needs at sampling time)."""

    task: str
    steps: int = 1000
    batch: int = 4
    lr: float = 1e-4
    rank: int = LORA_RANK
    seed: int = 0
    save_every: int = 500
    joint_steps: int | None = None
    lambda_img: float = 0.5
    lambda_lpips: float = 0.1
    lpips: str | None = None
    caption_dropout: float = 0.1


@dataclass(eq=False)
class LatentSet:
    """Encoded pairs: ``condition`` (n, N, D) and ``targets`` (branches, n, N, D) packed latents
    of latent size ``latent_hw``, token ``grid``; ``images``: the target images (branches, n, 3,
    S, S) in [0, 1] for the shading loss."""

    condition: torch.Tensor
    targets: torch.Tensor
    images: torch.Tensor
    latent_hw: tuple[int, int]

    @property
    def grid(self) -> tuple[int, int]:
        return self.latent_hw[0] // 2, self.latent_hw[1] // 2


@torch.no_grad()
def encode_samples(components: Components, samples: dict[str, np.ndarray], task: str) -> LatentSet:
    """Encode the condition and targets of ``task`` once (the VAE is frozen)."""
    cond_name, target_names = TASK_DATA[task]

    def to_tensor(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a.transpose(0, 3, 1, 2))).to(components.device, components.dtype)

    def enc(a: np.ndarray) -> torch.Tensor:
        return torch.cat([encode(components.vae, to_tensor(a[i : i + 8])) for i in range(0, len(a), 8)])

    cond = enc(samples[cond_name])
    targets = [enc(samples[t]) for t in target_names]
    images = torch.stack([to_tensor(samples[t]).float() for t in target_names])
    return LatentSet(pack(cond), torch.stack([pack(t) for t in targets]), images, tuple(cond.shape[-2:]))


def maps_from_images(albedo: torch.Tensor, normal: torch.Tensor, rsd: torch.Tensor) -> dict[str, torch.Tensor]:
    """Branch images (B, 3, S, S) in [0, 1] -> the five maps as ``shade_ggx`` takes them: albedo
    linear (B, 3), decoded normal 2x − 1 (B, 3), roughness, specular, displacement mm (B, 1)."""
    return {
        "albedo": srgb_to_linear_torch(albedo),
        "normal": normal * 2.0 - 1.0,
        "roughness": rsd[:, 0:1],
        "specular": rsd[:, 1:2],
        "displacement": (rsd[:, 2:3] - 0.5) * 2.0 * RSD_DISPLACEMENT_MM,
    }


class ShadingSupervisor:
    """The shading loss's fixed template geometry and its camera/light sampling (Sec. 3.4).

    Geometry: ``facegeo.uv.geometry_maps`` of the model's mean shape at the texture size (model
    space, mm). Views: with probability 0.5 the camera sits at ``radius`` mm from the head's
    centre at a uniform azimuth over 360° and an elevation U(−20°, 20°); otherwise in front of
    the face (+Z) with N(0, (0.1·radius)²) mm jitter. The light comes from the camera direction
    perturbed by N(0, 0.35²) per component (renormalised), radiance U(2, 3); ambient U(0.15, 0.3).
    """

    def __init__(self, size: int, model=None, lpips: torch.nn.Module | None = None, radius: float = 600.0):
        from facegeo.model_files import load_model
        from facegeo.uv import geometry_maps, rasterize_uv

        model = load_model() if model is None else model
        geo = geometry_maps(model.mean_shape, model, rasterize_uv(model, size=size))

        def chw(a: np.ndarray) -> torch.Tensor:
            a = a[..., None] if a.ndim == 2 else a
            return torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1), dtype=np.float32))[None]

        self.position, self.normal, self.tangent = chw(geo.position), chw(geo.normal), chw(geo.tangent)
        self.mask = chw(geo.mask.astype(np.float32))
        self.centre = torch.from_numpy(model.mean_shape.mean(axis=0).astype(np.float32))
        self.radius = radius
        self.lpips = lpips

    def sample_views(self, batch: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``batch`` views: light_dirs (B, 1, 3), radiance (B, 1, 3), camera_pos (B, 3), ambient (B,)."""
        def u(lo: float, hi: float, *shape: int) -> torch.Tensor:
            return lo + (hi - lo) * torch.rand(*shape, generator=generator)

        orbit = torch.rand(batch, generator=generator) < 0.5
        azimuth = u(0, 2 * math.pi, batch)
        elevation = torch.deg2rad(u(-20, 20, batch))
        around = torch.stack([torch.cos(elevation) * torch.sin(azimuth), torch.sin(elevation), torch.cos(elevation) * torch.cos(azimuth)], 1)
        front = torch.tensor([0.0, 0.0, 1.0]).expand(batch, 3) + 0.1 * torch.randn(batch, 3, generator=generator) * torch.tensor([1.0, 1.0, 0.0])
        offset = torch.where(orbit[:, None], around, front)
        camera = self.centre + self.radius * offset
        direction = F.normalize(offset, dim=1)
        light = F.normalize(direction + 0.35 * torch.randn(batch, 3, generator=generator), dim=1)
        radiance = u(2.0, 3.0, batch, 1).expand(batch, 3)
        return light[:, None], radiance[:, None].contiguous(), camera, u(0.15, 0.3, batch)

    def shade(self, maps: dict[str, torch.Tensor], view: tuple[torch.Tensor, ...]):
        """``shade_ggx`` of the maps (:func:`maps_from_images`) on the template for ``view``."""
        light, radiance, camera, ambient = (v.to(maps["albedo"].device) for v in view)
        geo = [t.to(maps["albedo"].device) for t in (self.position, self.normal, self.tangent, self.mask)]
        return shade_ggx(maps["albedo"], maps["normal"], maps["roughness"], maps["specular"], maps["displacement"],
                         geo[0], geo[1], geo[2], geo[3], light, radiance, camera, ambient, s_disp=1.0)

    def losses(self, predicted: dict[str, torch.Tensor], target: dict[str, torch.Tensor], view: tuple[torch.Tensor, ...]) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(visibility-weighted MSE of the sRGB shaded textures, mean LPIPS or None)."""
        pred = self.shade(predicted, view)
        with torch.no_grad():
            ref = self.shade(target, view)
        weight = ref.visibility
        a, b = linear_to_srgb_torch(pred.shaded, clip=False), linear_to_srgb_torch(ref.shaded, clip=False)
        mse = (weight * (a - b) ** 2).sum() / (3.0 * weight.sum()).clamp_min(1e-6)
        perceptual = None
        if self.lpips is not None:
            perceptual = self.lpips(a * weight * 2 - 1, b * weight * 2 - 1).mean()
        return mse, perceptual


def flow_matching_step(components: Components, latents: LatentSet, task: str, index: torch.Tensor, generator: torch.Generator,
                       *, joint: bool = False, supervisor: ShadingSupervisor | None = None, lambda_img: float = 0.5,
                       lambda_lpips: float = 0.1, caption_dropout: float = 0.0, sigma: torch.Tensor | None = None,
                       noise: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """The losses of one batch (``index``: (b,) sample indices); call ``backward`` on ``"loss"``.

    The branches of ``task`` are stacked along the batch axis (branch-major), each with its own
    adapter; ``joint`` turns on cross-intrinsic attention and, with a ``supervisor``, the
    shading terms; ``caption_dropout`` swaps items' captions for the empty one. ``sigma`` (b,)
    and ``noise`` (branches·b, N, D) fix the draws (default: σ logit-normal, ε ~ N(0, I) from
    ``generator``). Returns ``loss``, ``diff`` and, when computed, ``img`` and ``lpips``."""
    transformer, device = components.transformer, components.device
    adapters = TASK_ADAPTERS[task]
    m, b = len(adapters), len(index)
    z0 = latents.targets[:, index].reshape(m * b, *latents.targets.shape[2:]).float()
    cond = latents.condition[index].repeat(m, 1, 1)
    prompt = torch.cat([components.prompt(a).expand(b, -1, -1) for a in adapters])
    if caption_dropout > 0:
        drop = (torch.rand(m * b, generator=generator) < caption_dropout).to(device)
        negative = components.prompt("negative").expand(m * b, -1, -1)
        if negative.shape[1] == prompt.shape[1]:
            prompt = torch.where(drop[:, None, None], negative, prompt)
    if sigma is None:
        sigma = torch.sigmoid(torch.randn(b, generator=generator))  # logit-normal (SD3, Flux trainers)
    sigma = sigma.float().repeat(m).to(device)
    noise = (torch.randn(z0.shape, generator=generator) if noise is None else noise.float()).to(device)
    z_sigma = (1 - sigma[:, None, None]) * z0 + sigma[:, None, None] * noise
    autocast = torch.autocast("cuda", dtype=torch.bfloat16) if device.type == "cuda" and torch.cuda.is_bf16_supported() else nullcontext()
    with ExitStack() as stack:
        stack.enter_context(mixed_adapters(transformer, [a for a in adapters for _ in range(b)]))
        if joint and m > 1:
            stack.enter_context(cross_intrinsic(transformer, m))
        stack.enter_context(autocast)
        v = velocity(transformer, z_sigma.to(components.dtype), cond, prompt, sigma, latents.grid).float()
    out = {"diff": F.mse_loss(v, noise - z0)}
    loss = out["diff"]
    if joint and supervisor is not None:
        z0_hat = z_sigma - sigma[:, None, None] * v
        images = decode(components.vae, unpack(z0_hat, *latents.latent_hw)).float().view(m, b, 3, *latents.images.shape[-2:])
        view = supervisor.sample_views(b, generator)
        predicted = maps_from_images(*images)
        target = maps_from_images(*latents.images[:, index])
        out["img"], perceptual = supervisor.losses(predicted, target, view)
        loss = loss + lambda_img * out["img"]
        if perceptual is not None:
            out["lpips"] = perceptual
            loss = loss + lambda_lpips * perceptual
    out["loss"] = loss
    return out


def validation_sigmas(points: int = 16) -> torch.Tensor:
    """(points,) noise levels at the mid-quantiles (k + ½)/points of the training density
    σ = sigmoid(N(0, 1)): the mean of a loss over them is a quadrature of its expectation under
    the training's σ sampling (points = 16: σ from 0.134 to 0.866)."""
    normal = torch.distributions.Normal(0.0, 1.0)
    return torch.sigmoid(normal.icdf((torch.arange(points, dtype=torch.float64) + 0.5) / points)).float()


def validation_draws(latents: LatentSet, task: str, *, points: int = 16, repeats: int = 2,
                     seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The fixed evaluation set of :func:`validation_loss`: ``index`` (r·n,) every sample
    ``repeats`` times, ``sigmas`` (points,) from :func:`validation_sigmas`, ``noise`` (points,
    branches·r·n, N, D) standard normal drawn from ``seed`` (branch-major, as
    :func:`flow_matching_step` stacks the branches)."""
    index = torch.arange(latents.condition.shape[0]).repeat(repeats)
    generator = torch.Generator().manual_seed(seed)
    shape = (points, len(TASK_ADAPTERS[task]) * len(index), *latents.targets.shape[2:])
    return index, validation_sigmas(points), torch.randn(shape, generator=generator)


@torch.no_grad()
def validation_loss(components: Components, latents: LatentSet, task: str, *, points: int = 16, repeats: int = 2,
                    seed: int = 0, joint: bool = False) -> torch.Tensor:
    """Flow-matching loss L_diff on a fixed evaluation set (:func:`validation_draws`): every
    sample at each σ of :func:`validation_sigmas` with ``repeats`` noise draws fixed by ``seed``,
    the fixed captions. Calls before and after training see the same (σ, ε), unlike the running
    training loss, so their ratio measures what training changed. ``joint``: the materials task's
    cross-intrinsic attention. Returns (points,) float32, the loss at each σ (mean over samples,
    branches and repeats)."""
    index, sigmas, noise = validation_draws(latents, task, points=points, repeats=repeats, seed=seed)
    unused = torch.Generator()  # every draw is given; the step samples nothing
    losses = [flow_matching_step(components, latents, task, index, unused, joint=joint, sigma=sigma.expand(len(index)),
                                 noise=eps)["diff"] for sigma, eps in zip(sigmas, noise)]
    return torch.stack(losses).float().cpu()


def _latest_checkpoint(run: Path) -> Path | None:
    found = sorted((int(p.name.split("-")[1]), p) for p in run.glob("checkpoint-*") if (p / "state.pt").is_file())
    return found[-1][1] if found else None


def train_lora(components: Components, latents: LatentSet, config: TrainConfig, run: str | os.PathLike[str], *,
               resume: bool = False, log: Callable[[str], None] = print, progress: bool = True) -> list[dict[str, float]]:
    """Train the adapters of ``config.task`` on ``latents`` (:func:`encode_samples`) into the run
    folder ``run`` (module docstring). The adapters are added to ``components.transformer`` if it
    lacks them. Returns the metrics rows of this call."""
    from tqdm import tqdm

    from facegeo.staged_output import StagedOutput, atomic_write_bytes

    task = config.task
    if task not in TASK_DATA:
        raise ValueError(f"task: expected one of {', '.join(TASK_DATA)}, got {task!r}")
    run = Path(run)
    run.mkdir(parents=True, exist_ok=True)
    transformer = components.transformer
    adapters = TASK_ADAPTERS[task]
    existing = set(getattr(transformer, "peft_config", {}) or {})
    add_adapters(transformer, [a for a in adapters if a not in existing], config.rank)
    params = lora_parameters(transformer, adapters)
    transformer.requires_grad_(False)
    for p in params:  # master weights in float32 even on a bfloat16 backbone
        p.data = p.data.float()
        p.requires_grad_(True)
    optimizer = torch.optim.AdamW(params, lr=config.lr)
    generator = torch.Generator().manual_seed(config.seed)
    start = 0
    latest = _latest_checkpoint(run) if resume else None
    if latest is not None:
        state = torch.load(latest / "state.pt", map_location="cpu", weights_only=False)
        named = dict(transformer.named_parameters())
        with torch.no_grad():
            for name, value in state["lora"].items():
                named[name].copy_(value)
        optimizer.load_state_dict(state["optimizer"])
        generator.set_state(state["generator"])
        start = int(state["step"])
        log(f"resumed from {latest} at step {start}")
    joint_from = config.steps if task != "materials" else config.steps - (config.joint_steps if config.joint_steps is not None else config.steps // 2)
    supervisor = None
    if task == "materials" and joint_from < config.steps:
        lpips = None
        if config.lpips:
            from facegeo.texturing.diffusion.lpips import load_lpips

            lpips = load_lpips(config.lpips).to(components.device)
        else:
            log("note: no LPIPS checkpoint given (--lpips): the LPIPS term of the shading loss is dropped")
        supervisor = ShadingSupervisor(latents.images.shape[-1], lpips=lpips)
    n = latents.condition.shape[0]
    fields = ["step", "stage", "loss", "diff", "img", "lpips", "lr", "seconds"]
    csv_path = run / "metrics.csv"
    new_file = not csv_path.exists() or start == 0
    if not new_file:  # drop rows logged after the checkpoint we resume from
        with open(csv_path, newline="") as handle:
            kept = [r for r in csv.DictReader(handle) if int(r["step"]) <= start]
        with open(csv_path, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=fields)
            writer.writeheader()
            writer.writerows(kept)
    rows: list[dict[str, float]] = []
    transformer.train()
    with open(csv_path, "w" if new_file else "a", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=fields)
        if new_file:
            writer.writeheader()
        bar = tqdm(range(start, config.steps), initial=start, total=config.steps, desc=f"train-lora {task}", disable=not progress)
        for step in bar:
            t0 = time.perf_counter()
            joint = step >= joint_from
            index = torch.randint(0, n, (config.batch,), generator=generator)  # with replacement, also when batch > n
            out = flow_matching_step(components, latents, task, index, generator, joint=joint, supervisor=supervisor,
                                     lambda_img=config.lambda_img, lambda_lpips=config.lambda_lpips,
                                     caption_dropout=config.caption_dropout)
            optimizer.zero_grad(set_to_none=True)
            out["loss"].backward()
            optimizer.step()
            row = {"step": step + 1, "stage": 2 if joint and task == "materials" else 1, "lr": config.lr,
                   "seconds": time.perf_counter() - t0, **{k: float(v.detach()) for k, v in out.items()}}
            writer.writerow({k: row.get(k, "") for k in fields})
            rows.append(row)
            bar.set_postfix(loss=f"{row['loss']:.4f}")
            if (step + 1) % config.save_every == 0 or step + 1 == config.steps:
                handle.flush()
                state = {"lora": {k: p.detach().cpu() for k, p in transformer.named_parameters() if p.requires_grad},
                         "optimizer": optimizer.state_dict(), "generator": generator.get_state(), "step": step + 1,
                         "config": asdict(config)}
                path = run / f"checkpoint-{step + 1}" / "state.pt"
                path.parent.mkdir(exist_ok=True)
                buffer = io.BytesIO()
                torch.save(state, buffer)
                atomic_write_bytes(path, buffer.getvalue())
    transformer.eval()
    for name in adapters:
        with StagedOutput(run / name) as stage:
            transformer.save_lora_adapter(stage.staging_dir, adapter_name=name)
    return rows
