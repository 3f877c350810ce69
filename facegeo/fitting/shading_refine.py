"""Analysis by synthesis: identity, expression and pose refined against the photo's shading.

After the landmark fit and the photometric stage (albedo β, SH lighting γ), the photo holds
more than its landmarks: how the skin's brightness changes over cheeks, chin and nose says how
the surface turns. This stage minimises, in torch on the CPU,

    E = E_landmarks(R, t, α, δ) + ‖α‖² + prior(δ)
        + λ · Σ_v ρ((I(π(R·S_v + t)) − a_v ⊙ Y(n_v)·γ) / σ_ph) / N,

with the landmark term of :class:`~facegeo.fitting.landmark_problem.LandmarkProblem` at its final
correspondences (its noise σ and weights as the landmark fit left them), a_v the fitted albedo,
Y the 9 SH basis values of the current normals n_v (which move with α and δ), I the photo
(linear RGB) sampled bilinearly at the projected vertex, ρ Huber's loss, σ_ph the robust spread
of the residuals at the start, N the number of samples and λ = :attr:`ShadingSettings.weight`
the evidence the shading gets, in landmark units. Samples are the vertices of the skin mask
that the camera saw at the start (fixed: the refinement moves the face by little). Adam with
the expression weights projected back into their range after each step.

Why by hand: the term must be differentiable with respect to the shape through both the
projection and the normals; no library renders a morphable model's vertices that way on a CPU
without a GPU rasteriser, and at vertex resolution none is needed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from facegeo.camera import project, rotation_from_axis_angle
from facegeo.fitting.landmark_problem import LandmarkProblem
from facegeo.fitting.result import Fit
from facegeo.lighting import sh_basis
from facegeo.morphable_model import MorphableModel
from facegeo.normals import vertex_normals_torch
from facegeo.skin_mask import skin_vertex_mask
from facegeo.visibility import vertex_visibility

__all__ = ["ShadingSettings", "DEFAULT_SHADING", "SHADING_THREADS", "refine_with_shading"]


@dataclass(frozen=True)
class ShadingSettings:
    """Knobs of the shading stage: ``iterations`` Adam steps; ``weight`` λ (the shading's
    evidence in landmark units); ``learning_rate`` of α (σ units per step; δ, rotation and
    translation get fixed fractions of it, scaled to their units)."""

    iterations: int = 40
    weight: float = 20.0
    learning_rate: float = 0.03


#: The default shading stage.
DEFAULT_SHADING = ShadingSettings()

#: torch threads of the stage: its tensors are small (a few thousand vertices), and on a loaded
#: 2-core machine two threads made the normals 5× slower than one (18 against 90 ms).
SHADING_THREADS = 1


def _bounds(model: MorphableModel) -> tuple[torch.Tensor, torch.Tensor]:
    lower, upper = model.expression_range
    return torch.as_tensor(lower, dtype=torch.float64), torch.as_tensor(upper, dtype=torch.float64)


def refine_with_shading(model: MorphableModel, result: Fit, problem: LandmarkProblem, noise: float,
                        image_linear: np.ndarray, expression_scale: np.ndarray, expression_rate: np.ndarray,
                        settings: ShadingSettings = DEFAULT_SHADING) -> tuple[Fit, dict[str, Any]]:
    """``result`` refined against the photo's shading (a new :class:`Fit`: α, δ, rotation,
    translation, vertices, shape_vertices refined), and the stage's statistics.

    Args:
        model: the morphable model.
        result: a fit with its photometric stage done (β, γ).
        problem: the landmark problem of that fit, slid at its final state.
        noise: the landmark noise σ (inter-ocular units) the landmark fit ended with.
        image_linear: (H, W, 3) float32 linear RGB photo in [0, 1].
        expression_scale, expression_rate: (n_exp,) the δ prior's scales and rates.
        settings: the stage's knobs.
    Returns:
        ``(refined fit, statistics for info["shading"]: samples, energies before and after, seconds)``.
    """
    threads = torch.get_num_threads()
    torch.set_num_threads(SHADING_THREADS)
    try:
        return _refine(model, result, problem, noise, image_linear, expression_scale, expression_rate, settings)
    finally:
        torch.set_num_threads(threads)


def _refine(model: MorphableModel, result: Fit, problem: LandmarkProblem, noise: float, image_linear: np.ndarray,
            expression_scale: np.ndarray, expression_rate: np.ndarray, settings: ShadingSettings) -> tuple[Fit, dict[str, Any]]:
    start = time.perf_counter()
    f64 = torch.float64
    normals0 = model.vertex_normals(torch.from_numpy(result.vertices)).numpy()
    seen = vertex_visibility(result.vertices, model.triangles, normals0, result.camera) & skin_vertex_mask(model)
    use_np = np.flatnonzero(seen)
    if len(use_np) < 50:
        return {"skipped": "fewer than 50 visible skin vertices"}
    # the shape is evaluated on the samples and their one-ring only: their normals are exact there
    triangles_np = np.asarray(model.triangles)
    ring = np.isin(triangles_np, use_np).any(axis=1)
    sub = np.unique(triangles_np[ring])
    local = np.full(model.n_vertices, -1, dtype=np.int64)
    local[sub] = np.arange(len(sub))
    sub_triangles = torch.from_numpy(local[triangles_np[ring]])
    use_local = torch.from_numpy(local[use_np])
    mean_sub = torch.from_numpy(model.mean_shape[sub].astype(np.float64))
    id_sub = torch.from_numpy(model.id_basis[:, sub].astype(np.float64)).reshape(model.n_id, -1)
    exp_sub = torch.from_numpy(model.exp_basis[:, sub].astype(np.float64)).reshape(model.n_exp, -1)
    use = torch.from_numpy(use_np)
    albedo = model.tensor("mean_albedo", f64)[use]
    if model.n_tex:
        albedo = albedo + torch.einsum("k,kvc->vc", torch.from_numpy(result.beta).double(), model.tensor("tex_basis", f64)[:, use])
    gamma = torch.from_numpy(result.gamma).double()
    height, width = image_linear.shape[:2]
    image = torch.from_numpy(np.ascontiguousarray(image_linear.transpose(2, 0, 1))).double()[None]
    camera = result.camera

    mean_lm = torch.from_numpy(problem.mean_lm)
    id_lm = torch.from_numpy(problem.id_lm)
    exp_lm = torch.from_numpy(problem.exp_lm)
    targets = torch.from_numpy(problem.targets)
    sqrt_w = torch.from_numpy(problem.sqrt_w)[:, None]
    inv_var = torch.from_numpy(np.asarray(expression_scale, np.float64) ** -2)
    rate = torch.from_numpy(np.asarray(expression_rate, np.float64))
    lower, upper = _bounds(model)
    r0 = torch.from_numpy(result.rotation.astype(np.float64))
    t0 = torch.from_numpy(result.translation.astype(np.float64))
    alpha = torch.from_numpy(result.alpha.astype(np.float64)).requires_grad_()
    delta = torch.from_numpy(result.delta.astype(np.float64)).requires_grad_()
    omega = torch.zeros(3, dtype=f64, requires_grad=True)
    shift = torch.zeros(3, dtype=f64, requires_grad=True)

    def pose() -> tuple[torch.Tensor, torch.Tensor]:
        return r0 @ rotation_from_axis_angle(omega), t0 + 10.0 * shift

    def photometric(rotation: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
        shape = mean_sub + (alpha @ id_sub + delta @ exp_sub).reshape(-1, 3)
        normals = vertex_normals_torch(shape @ rotation.T, sub_triangles)[use_local]
        uv = project(shape[use_local], rotation, translation, camera)
        grid = torch.stack([2.0 * uv[:, 0] / width - 1.0, 2.0 * uv[:, 1] / height - 1.0], dim=-1)[None, None]
        observed = torch.nn.functional.grid_sample(image, grid, mode="bilinear", align_corners=False)[0, :, 0].T
        return observed - albedo * (sh_basis(normals) @ gamma.T)

    def landmark_energy(rotation: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
        points = mean_lm + torch.einsum("k,kvc->vc", alpha, id_lm) + torch.einsum("k,kvc->vc", delta, exp_lm)
        r = (project(points, rotation, translation, camera) - targets) * sqrt_w / noise
        return (r * r).sum() + alpha @ alpha + (delta * delta) @ inv_var + 2.0 * (rate @ delta)

    with torch.no_grad():
        rotation, translation = pose()
        residual0 = photometric(rotation, translation).norm(dim=1)
        sigma = float(1.4826 * residual0.median()) + 1e-6
    n = float(len(use))

    def energy() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        rotation, translation = pose()
        photo = photometric(rotation, translation) / sigma
        photo = torch.nn.functional.huber_loss(photo, torch.zeros_like(photo), reduction="sum", delta=1.0)
        photo = settings.weight * photo / n
        lan = landmark_energy(rotation, translation)
        return lan + photo, lan, photo

    lr = settings.learning_rate
    # Adam written out: torch.optim's import pulls in torch._dynamo (seconds on a CPU machine)
    groups = [(alpha, lr), (delta, lr * 0.3), (omega, lr * 0.01), (shift, lr * 0.1)]
    moments = [(torch.zeros_like(p), torch.zeros_like(p)) for p, _ in groups]
    with torch.no_grad():
        e_start, lan_start, photo_start = (float(v) for v in energy())
    best = (e_start, alpha.detach().clone(), delta.detach().clone(), omega.detach().clone(), shift.detach().clone())
    beta1, beta2 = 0.9, 0.999
    for step in range(1, settings.iterations + 1):
        for p, _ in groups:
            p.grad = None
        total, _, _ = energy()
        total.backward()
        with torch.no_grad():
            for (p, step_size), (m, v) in zip(groups, moments):
                m.mul_(beta1).add_(p.grad, alpha=1 - beta1)
                v.mul_(beta2).addcmul_(p.grad, p.grad, value=1 - beta2)
                p -= step_size * (m / (1 - beta1**step)) / ((v / (1 - beta2**step)).sqrt() + 1e-8)
            delta.copy_(torch.minimum(torch.maximum(delta, lower), upper))
            value = float(energy()[0])
            if value < best[0]:
                best = (value, alpha.detach().clone(), delta.detach().clone(), omega.detach().clone(), shift.detach().clone())
    _, a_best, d_best, w_best, s_best = best
    with torch.no_grad():
        alpha.copy_(a_best), delta.copy_(d_best), omega.copy_(w_best), shift.copy_(s_best)
        e_end, lan_end, photo_end = (float(v) for v in energy())
        rotation, translation = pose()
        shape = model.shape(alpha.float(), delta.float())
    shape_vertices, rotation_np = shape.numpy().astype(np.float32), rotation.numpy().astype(np.float32)
    translation_np = translation.numpy().astype(np.float32)
    refined = replace(result, alpha=a_best.numpy().astype(np.float32), delta=d_best.numpy().astype(np.float32),
                      rotation=rotation_np, translation=translation_np, shape_vertices=shape_vertices,
                      vertices=(shape_vertices @ rotation_np.T + translation_np).astype(np.float32))
    return refined, {"samples": int(len(use)), "energy": [e_start, e_end], "landmark_energy": [lan_start, lan_end],
            "shading_energy": [photo_start, photo_end], "sigma_linear": sigma, "seconds": time.perf_counter() - start}

