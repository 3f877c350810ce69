"""The self-supervised objective of Sec. 3.2, batched and differentiable:

    L = λ_lan·L_lan + λ_pho·L_pho + λ_per·L_per + λ_reg·L_reg

- L_lan: :func:`facegeo.landmarks.scheme.landmark_loss` (88-point weights, inter-ocular scale)
  on :func:`facegeo.project` of ``MorphableModel.shape(α, δ)``'s landmark vertices, the 16 jaw
  points (all but the chin) sliding along the projected jaw contour as in ``fit_landmarks``.
- L_pho: the crop (linearised sRGB) sampled bilinearly at the projected skin vertices that face
  the camera, against albedo(β) × SH irradiance(γ, camera-space normals) (``facegeo.lighting``);
  mean per-vertex colour distance. Sampled at vertices, not rasterised: the sampling positions
  carry the gradient to the geometry without a differentiable rasteriser (none runs on CPU
  without extra compiled packages), and the model's ~1 px vertex spacing in a 224 px crop loses
  little. Visibility: facing the camera and not behind another vertex in a coarse vertex
  z-buffer; the skin mask keeps out eyes, brows and lips.
- L_per: 1 − cos between a local embedding network's outputs for the crop and for the crop
  with the predicted face composited in (z-buffer from ``facegeo.uv.rasterize_mesh``, colours
  interpolated differentiably); skipped with a logged note when no checkpoint is configured.
- L_reg: the negative log prior of ``fit_landmarks`` (:class:`facegeo.fitting.FitPriors`:
  ‖α‖² + Σ (δ_k/s_δ)² + 2 Σ |δ_k|/τ for blendshapes, ‖δ‖² for PCA expressions, on the head's
  unconstrained δ) weighted as that MAP fit weighs it against the landmark term: × σ²/Σw, with
  σ² the landmark noise per coordinate that the network has now (half the batch's mean L_lan,
  no gradient, never below ``noise_floor``²) and Σw the landmark weights' sum. So early in
  training, when the predicted landmarks are far off, the prior keeps α and δ near the mean
  face, and it loosens as the landmarks get closer (as the fit's noise re-estimation does); a
  fixed weight either lets α and δ absorb the pose error (adding shape error) or, set for the
  early error, stops them learning later. Plus small ridge terms on β and γ − ambient white.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from torch.nn import functional as F

from facegeo.camera import Camera, project
from facegeo.colour import linear_to_srgb_torch, srgb_to_linear_torch
from facegeo.errors import InputError
from facegeo.fitting import DEFAULT_PRIORS, FitPriors
from facegeo.landmarks.scheme import CHIN, IBUG68, LANDMARK_WEIGHTS, OUTER_EYE_CORNERS, landmark_loss
from facegeo.lighting import AMBIENT_WHITE, sh_irradiance
from facegeo.morphable_model import MorphableModel
from facegeo.regressor.config import LossConfig
from facegeo.skin_mask import skin_vertex_mask
from facegeo.uv import rasterize_mesh

__all__ = ["BatchCamera", "Objective", "landmark_weights", "slide_jaw"]

log = logging.getLogger("facegeo.regressor")


class BatchCamera(NamedTuple):
    """Per-sample pinhole intrinsics, (B, 1) tensors in crop pixels. :func:`facegeo.project`
    reads only ``focal``, ``cx`` and ``cy``, so this stands in for a :class:`Camera` there."""

    focal: torch.Tensor
    cx: torch.Tensor
    cy: torch.Tensor

    @classmethod
    def of(cls, intrinsics: torch.Tensor) -> "BatchCamera":
        """From (B, 3) = (focal, cx, cy)."""
        return cls(*(c[:, None] for c in intrinsics.float().unbind(-1)))


def landmark_weights(scheme: str) -> np.ndarray:
    """(88,) float32 weights: ``hybrid88`` = LANDMARK_WEIGHTS, ``ibug68`` = 1 on the 68 iBUG
    points and 0 on the 20 MediaPipe lip points."""
    if scheme == "hybrid88":
        return LANDMARK_WEIGHTS.copy()
    w = np.zeros(88, np.float32)
    w[IBUG68] = 1.0
    return w


def slide_jaw(points_cam: torch.Tensor, landmark_indices: np.ndarray, targets: torch.Tensor,
              camera: "BatchCamera | Camera") -> torch.Tensor:
    """The 88 projected landmarks with each jaw point but the chin moved to the point of its
    side's projected jaw polyline nearest to its target; as in ``fit_landmarks``, the point is
    interpolated on the 3D edge with the parameter found in the image, then projected.

    Args:
        points_cam: (B, V, 3) camera-space model vertices, mm (or any vertex subset holding
            the landmark vertices, with ``landmark_indices`` into it).
        landmark_indices: (88,) the frontal landmark vertices (0..16 = the jaw polyline).
        targets: (B, 88, 2) px; NaN rows keep their frontal correspondence.
        camera: the intrinsics (per sample or shared).
    Returns:
        (B, 88, 2) px; differentiable in ``points_cam`` (the choice of edge is not).
    """
    idx = (landmark_indices.long() if isinstance(landmark_indices, torch.Tensor)  # a read-only array copied (torch warns on sharing it)
           else torch.as_tensor(np.require(landmark_indices, requirements="W"), dtype=torch.long))
    eye, zero = torch.eye(3).expand(len(points_cam), 3, 3), torch.zeros(len(points_cam), 3)
    points = points_cam[:, idx].clone()  # (B, 88, 3)
    jaw = idx[:17]
    for contour, rows in ((jaw[: CHIN + 1], list(range(0, CHIN))), (jaw[CHIN:].flip(0), list(range(CHIN + 1, 17)))):
        ends = points_cam[:, contour]  # (B, P, 3)
        q = targets[:, rows]  # (B, J, 2)
        with torch.no_grad():
            poly = project(ends, eye, zero, camera)
            a, ab = poly[:, :-1], poly[:, 1:] - poly[:, :-1]
            t = (((q[:, :, None] - a[:, None]) * ab[:, None]).sum(-1) / (ab * ab).sum(-1).clamp_min(1e-12)[:, None]).clamp(0, 1)
            d = ((a[:, None] + t[..., None] * ab[:, None] - q[:, :, None]) ** 2).sum(-1)  # (B, J, S)
            seg = d.argmin(-1)  # (B, J)
            t_best = t.gather(-1, seg[..., None])  # (B, J, 1)
        pa = ends.gather(1, seg[..., None].expand(-1, -1, 3))
        pb = ends.gather(1, (seg + 1)[..., None].expand(-1, -1, 3))
        finite = torch.isfinite(q).all(-1, keepdim=True)
        points[:, rows] = torch.where(finite, (1 - t_best) * pa + t_best * pb, points[:, rows])
    return project(points, eye, zero, camera)


def _unoccluded(posed: torch.Tensor, grid: torch.Tensor, cells: int, tolerance_mm: float = 5.0) -> torch.Tensor:
    """(B, V) bool: vertices within ``tolerance_mm`` of the nearest vertex depth in their cell of a
    ``cells``² grid over the crop. A batched vertex z-buffer in torch: ``facegeo.visibility``
    splats every triangle in NumPy (~80 ms a face), too slow for every training sample."""
    b, v = posed.shape[:2]
    cell = ((grid + 1) / 2 * cells).long().clamp(0, cells - 1)
    key = (torch.arange(b)[:, None] * cells + cell[..., 1]) * cells + cell[..., 0]
    depth = -posed[..., 2]
    buffer = torch.full((b * cells * cells,), float("inf")).scatter_reduce(0, key.reshape(-1), depth.reshape(-1), "amin")
    return depth <= buffer[key] + tolerance_mm


class Objective:
    """L and its terms for a batch of predictions.

    Args:
        model: the morphable model. config: the loss section. image_size: the crop side S.
        priors: the MAP fit's priors (L_reg).
    """

    def __init__(self, model: MorphableModel, config: LossConfig, image_size: int, priors: FitPriors = DEFAULT_PRIORS):
        self.model, self.config, self.size, self.priors = model, config, image_size, priors
        self.weights = torch.from_numpy(landmark_weights(config.landmarks))
        self.skin = torch.from_numpy(skin_vertex_mask(model))
        self.landmark_subset, rows = np.unique(model.landmark_indices, return_inverse=True)
        self.landmark_rows = rows.astype(np.int64)
        self.embed: torch.nn.Module | None = None
        if config.per > 0 and config.perceptual_checkpoint:
            path = Path(config.perceptual_checkpoint)
            try:
                self.embed = torch.jit.load(str(path), map_location="cpu").eval()
            except (OSError, RuntimeError, ValueError) as exc:
                raise InputError(path, "perceptual_checkpoint", "a TorchScript embedding network file", str(exc).splitlines()[0]) from None
            for p in self.embed.parameters():  # frozen (ScriptModules have no requires_grad_)
                p.requires_grad_(False)
        elif config.per > 0:
            log.info("L_per skipped: no perceptual_checkpoint in the loss config")

    def __call__(self, params: dict[str, torch.Tensor], image: torch.Tensor, intrinsics: torch.Tensor,
                 landmarks: torch.Tensor) -> dict[str, torch.Tensor]:
        """Per-sample terms (B,) ``lan``, ``pho``, ``per``, ``reg`` and the scalar ``total``.

        Args:
            params: :meth:`MSSFRegressor.decode`'s output.
            image: (B, 3, S, S) sRGB crop in [0, 1]. intrinsics: (B, 3) focal, cx, cy (px).
            landmarks: (B, 88, 2) target landmarks in crop pixels (NaN = missing).
        """
        c, model = self.config, self.model
        cam = BatchCamera.of(intrinsics)
        need_colour = c.pho > 0 or self.embed is not None
        # landmarks only: evaluate the model at the landmark vertices alone (V/100 of the work)
        subset = None if need_colour else self.landmark_subset
        shape = model.shape(params["alpha"], params["delta"], subset)  # (B, V or K, 3) mm
        posed = shape @ params["rotation"].transpose(1, 2) + params["translation"][:, None]
        corners = landmarks[:, OUTER_EYE_CORNERS]
        iod = torch.linalg.norm(corners[:, 0] - corners[:, 1], dim=-1).nan_to_num(1.0).clamp_min(1.0)
        indices = model.landmark_indices if subset is None else self.landmark_rows
        lan = landmark_loss(slide_jaw(posed, indices, landmarks, cam), landmarks, self.weights, iod)
        terms = {"lan": lan}
        zero = torch.zeros_like(lan)
        if need_colour:
            normals = model.vertex_normals(posed)
            colour = model.albedo(params["beta"]) * sh_irradiance(normals, params["gamma"])  # (B, V, 3) linear
        if c.pho > 0:
            uv = project(posed, torch.eye(3).expand(len(posed), 3, 3), torch.zeros(len(posed), 3), cam)
            terms["pho"] = self._photometric(image, uv, posed, normals, colour)
        else:
            terms["pho"] = zero
        terms["per"] = self._perceptual(image, posed.detach(), colour, cam) if self.embed is not None else zero
        terms["reg"] = self._prior(params, lan, landmarks)
        total = c.lan * lan + c.pho * terms["pho"] + c.per * terms["per"] + c.reg * terms["reg"]
        terms["total"] = total.mean()
        return terms

    def _prior(self, params: dict[str, torch.Tensor], lan: torch.Tensor, landmarks: torch.Tensor) -> torch.Tensor:
        """(B,) L_reg (module docstring)."""
        c, p = self.config, self.priors
        delta = params.get("delta_free", params["delta"])
        if self.model.expression_kind == "blendshape":
            exp = (delta / p.expression_scale).pow(2).sum(-1) + 2.0 * p.expression_rate * delta.abs().sum(-1)
        else:
            exp = delta.pow(2).sum(-1)
        noise2 = (lan.detach().mean() / 2).clamp_min(p.noise_floor**2)
        w = torch.where(torch.isfinite(landmarks).all(-1), self.weights, torch.zeros_like(self.weights)).sum(-1)
        reg = noise2 / w.clamp_min(1.0) * (params["alpha"].pow(2).sum(-1) + exp)
        reg = reg + c.reg_sh * (params["gamma"] - torch.tensor(AMBIENT_WHITE)).pow(2).mean((-1, -2))
        if params["beta"].shape[-1]:
            reg = reg + c.reg_tex * params["beta"].pow(2).mean(-1)
        return reg

    def _photometric(self, image: torch.Tensor, uv: torch.Tensor, posed: torch.Tensor, normals: torch.Tensor,
                     colour: torch.Tensor) -> torch.Tensor:
        linear = srgb_to_linear_torch(image)
        grid = uv / self.size * 2 - 1  # corner-origin px -> grid_sample's [-1, 1] (align_corners=False)
        observed = F.grid_sample(linear, grid[:, :, None], mode="bilinear", align_corners=False)[..., 0].transpose(1, 2)
        with torch.no_grad():
            facing = (normals * -posed).sum(-1) > 0
            inside = ((grid > -1) & (grid < 1)).all(-1)
            use = (facing & inside & self.skin & _unoccluded(posed, grid, max(8, self.size // 4))).float()
        dist = ((colour - observed) ** 2).sum(-1).add(1e-8).sqrt()
        return (dist * use).sum(-1) / use.sum(-1).clamp_min(1.0)

    def _perceptual(self, image: torch.Tensor, posed: torch.Tensor, colour: torch.Tensor, cam: BatchCamera) -> torch.Tensor:
        tri = self.model.triangles
        rendered = []
        for b in range(len(image)):
            camera = Camera(float(cam.focal[b]), float(cam.cx[b]), float(cam.cy[b]), self.size, self.size)
            with torch.no_grad():
                tbuf, bary, _ = rasterize_mesh(posed[b].numpy(), tri, camera)
            mask = torch.from_numpy(tbuf >= 0)
            corners = torch.from_numpy(tri[np.maximum(tbuf, 0)])  # (S, S, 3)
            face = (colour[b][corners] * torch.from_numpy(bary)[..., None]).sum(-2)  # (S, S, 3) linear
            face = linear_to_srgb_torch(face).permute(2, 0, 1)
            rendered.append(torch.where(mask, face, image[b]))
        a = self.embed(image)
        r = self.embed(torch.stack(rendered))
        return 1 - F.cosine_similarity(a, r, dim=-1)
