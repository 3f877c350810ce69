"""Analysis-by-synthesis fitting of the morphable model to one photo (CPU, float32).

Stages (each timed in ``Fit.timings``):

1. **Pose** from landmarks with OpenCV's solvePnP (SQPnP on the 51 non-jaw iBUG points of the
   mean shape, then Levenberg–Marquardt refinement).
2. **Landmarks**: Levenberg–Marquardt on the pose, identity α and expression δ minimising

       E = L_lan + λ_id‖α‖² + λ_exp‖δ‖²,   L_lan = Σ w_i‖π(R·S_i + t) − q_i‖² / (Σ w_i · s²)

   with the 88-point weights of :mod:`facegeo.landmarks.scheme` and s the detected
   inter-ocular distance (so E does not depend on the image resolution). Coarse to fine
   (:data:`LANDMARK_SCHEDULE`): pose only, then pose + the first identity components +
   expression, then everything. Before every step the 16 jaw points (all but the chin) are
   re-assigned to the point of the projected model jaw contour nearest to the detected point
   (eos's sliding contour, continuous along the contour's edges).
3. **Photometric** (``fit`` only): vertex colours sampled from the photo (linearised sRGB) at
   visible projected vertices (point-splat z-buffer + facing test) under a skin mask (the
   model's face region minus eyes, brows and lips) are explained by albedo(β) × SH irradiance
   (γ, camera-space normals). The loss is bilinear in β and γ, so it is minimised exactly by
   alternating regularised least squares; residuals beyond 3 robust σ (hair, glasses,
   specular highlights) are dropped between rounds.

Axes and units: DESIGN.md (mm, +Y up, camera looks down −Z); pixels as in :mod:`facegeo.camera`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from facegeo.camera import OPENCV_FROM_OPENGL, Camera, euler_from_rotation, project, rotation_from_axis_angle
from facegeo.colour import srgb_to_linear
from facegeo.errors import InputError
from facegeo.fit_checks import check_fit, check_landmarks
from facegeo.landmarks.detectors import FaceLandmarks, LandmarkDetector, get_detector
from facegeo.landmarks.scheme import CHIN, LANDMARK_WEIGHTS, N_LANDMARKS, inter_ocular_distance
from facegeo.lighting import AMBIENT_WHITE, N_SH, sh_basis
from facegeo.model_files import load_model
from facegeo.morphable_model import MorphableModel
from facegeo.photo import Photo, as_rgb_uint8, load_photo
from facegeo.visibility import vertex_visibility

__all__ = ["Fit", "fit", "fit_landmarks", "LandmarkStage", "LANDMARK_SCHEDULE", "REGULARISATION"]


@dataclass(frozen=True)
class LandmarkStage:
    """One coarse-to-fine stage: Levenberg–Marquardt ``iterations`` with the pose, the first
    ``n_id`` identity components (None: all) and, if ``expression``, all expression components."""

    name: str
    iterations: int
    n_id: int | None
    expression: bool


#: The documented coarse-to-fine schedule of the landmark stage (error against iterations in
#: benchmarks/RESULTS.md).
LANDMARK_SCHEDULE: tuple[LandmarkStage, ...] = (
    LandmarkStage("pose", 8, 0, False),
    LandmarkStage("coarse", 8, 20, True),
    LandmarkStage("fine", 20, None, True),
)

#: A stage stops early once a step lowers E by less than this fraction.
CONVERGED_RELATIVE_DECREASE = 1e-6

#: Prior weights λ of E (coefficients are in σ units, L_lan in inter-ocular units squared):
#: λ ≈ σ_lm² / N with landmark noise σ_lm ≈ 1.3 % of the inter-ocular distance and N = 176
#: coordinates; ``tex`` and ``sh`` regularise the photometric least squares.
REGULARISATION = {"id": 1e-6, "exp": 1e-6, "tex": 1e-2, "sh": 1e-3}


@dataclass
class Fit:
    """The result of a fit. Arrays are NumPy float32 unless stated.

    alpha (n_id,), delta (n_exp,), beta (n_tex,): coefficients in σ units (δ: blendshape weights
    for ICT). gamma (3, 9): SH coefficients per RGB channel (total, no hidden offset).
    rotation (3, 3), translation (3,) mm: X_c = R·X + t. camera: the intrinsics used.
    vertices (V, 3): posed, camera space, mm. shape_vertices (V, 3): model space, unposed, mm.
    landmarks (88, 2) px: the targets; landmarks_fitted (88, 2) px: the model's projections with
    the final (slid) correspondences ``landmark_vertices`` (88,) int64.
    landmark_errors_px (88,): per-point distance; landmark_rms_px: their RMS over valid points.
    timings: seconds per stage; info: detector notes, iterations, photometric statistics.
    """

    alpha: np.ndarray
    delta: np.ndarray
    beta: np.ndarray
    gamma: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    camera: Camera
    vertices: np.ndarray
    shape_vertices: np.ndarray
    landmarks: np.ndarray
    landmarks_fitted: np.ndarray
    landmark_vertices: np.ndarray
    landmark_errors_px: np.ndarray
    landmark_rms_px: float
    timings: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready parameters, camera, per-point landmark errors, timings and info."""
        yaw, pitch, roll = euler_from_rotation(self.rotation)
        return {
            "alpha": self.alpha.tolist(),
            "delta": self.delta.tolist(),
            "beta": self.beta.tolist(),
            "gamma": self.gamma.tolist(),
            "rotation": self.rotation.tolist(),
            "euler_deg": {"yaw": yaw, "pitch": pitch, "roll": roll},
            "translation_mm": self.translation.tolist(),
            "camera": self.camera.as_dict(),
            "landmarks_px": self.landmarks.tolist(),
            "landmarks_fitted_px": self.landmarks_fitted.tolist(),
            "landmark_vertices": self.landmark_vertices.tolist(),
            "landmark_errors_px": self.landmark_errors_px.tolist(),
            "landmark_rms_px": self.landmark_rms_px,
            "timings_s": self.timings,
            "info": self.info,
        }


# ---------------------------------------------------------------------------------- pose init
def _initial_pose(model: MorphableModel, targets: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(R (3,3), t (3,)) in OpenGL camera axes from solvePnP on the non-jaw iBUG points."""
    ids = np.arange(17, 68)
    ok = np.isfinite(targets[ids]).all(axis=1)
    obj = model.mean_shape[model.landmark_indices[ids[ok]]].astype(np.float64)
    img = targets[ids[ok]].astype(np.float64)
    K = camera.matrix()
    iod_model = float(np.linalg.norm(model.mean_shape[model.landmark_indices[36]] - model.mean_shape[model.landmark_indices[45]]))
    iod_image = max(inter_ocular_distance(targets), 1.0)
    fallback_t = np.array([0.0, 0.0, -camera.focal * iod_model / iod_image])
    if len(obj) >= 6:
        ok_pnp, rvec, tvec = cv2.solvePnP(obj, img, K, None, flags=cv2.SOLVEPNP_SQPNP)
        if ok_pnp:
            rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, None, rvec, tvec)
            r_cv, _ = cv2.Rodrigues(rvec)
            rotation = OPENCV_FROM_OPENGL @ r_cv
            translation = OPENCV_FROM_OPENGL @ tvec.ravel()
            if translation[2] < 0 and np.all(np.isfinite(translation)):
                return rotation, translation
    return np.eye(3), fallback_t


# ---------------------------------------------------------------------------------- landmarks
class _LandmarkProblem:
    """Residuals of E over the landmark vertices, with the jaw points sliding along the contour.

    Each landmark is a point (1 − t)·S_a + t·S_b on a model edge (a = b, t = 0 for fixed points).
    The jaw contour is the model's frontal jaw polyline (landmark vertices 0→8 on the subject's
    right, 16→8 on the left); before each step every jaw point but the chin moves to the point of
    its side's projected polyline nearest to its detected position (eos's sliding contour, made
    continuous so no vertex spacing limits the fit).
    """

    def __init__(self, model: MorphableModel, targets: np.ndarray, camera: Camera, weights: np.ndarray):
        self.model, self.camera = model, camera
        jaw = model.landmark_indices[:17]
        self.contours = {"right": jaw[: CHIN + 1], "left": jaw[CHIN:][::-1]}
        self.subset = np.unique(model.landmark_indices)
        self.position = {int(v): i for i, v in enumerate(self.subset)}
        # float64 here: Gauss-Newton squares the Jacobian, and float32 cannot tell the last
        # sub-pixel decreases of the cost apart.
        idx = torch.from_numpy(self.subset)
        self.mean = model.tensor("mean_shape", torch.float64)[idx]
        self.id_basis = model.tensor("id_basis", torch.float64)[:, idx]
        self.exp_basis = model.tensor("exp_basis", torch.float64)[:, idx]
        valid = np.isfinite(targets).all(axis=1)
        w = np.where(valid, weights, 0.0).astype(np.float64)
        self.scale = max(inter_ocular_distance(targets), 1.0)
        self.sqrt_w = torch.tensor(np.sqrt(w / w.sum()) / self.scale, dtype=torch.float64)
        self.targets = torch.tensor(np.where(valid[:, None], targets, 0.0), dtype=torch.float64)
        rows = torch.tensor([self.position[int(v)] for v in model.landmark_indices])
        self.rows_a, self.rows_b = rows.clone(), rows.clone()
        self.t = torch.zeros(N_LANDMARKS, dtype=torch.float64)

    def points(self, alpha: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
        """(K, 3) model-space positions of the landmark vertices."""
        return self.mean + torch.einsum("k,kvc->vc", alpha, self.id_basis) + torch.einsum("k,kvc->vc", delta, self.exp_basis)

    def slide_jaw(self, rotation: torch.Tensor, translation: torch.Tensor, alpha: torch.Tensor, delta: torch.Tensor) -> None:
        """Move each jaw point (but the chin) to the nearest point of its projected contour."""
        with torch.no_grad():
            uv = project(self.points(alpha, delta), rotation, translation, self.camera)
        for side, jaw_points in (("right", range(0, CHIN)), ("left", range(CHIN + 1, 17))):
            rows = torch.tensor([self.position[int(v)] for v in self.contours[side]])
            a, b = uv[rows[:-1]], uv[rows[1:]]  # (S, 2) segment ends
            ab = b - a
            for j in jaw_points:
                q = self.targets[j]
                t = (((q - a) * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(1e-12)).clamp(0.0, 1.0)
                d = ((a + t[:, None] * ab - q) ** 2).sum(-1)
                s = int(torch.argmin(d))
                self.rows_a[j], self.rows_b[j], self.t[j] = rows[s], rows[s + 1], t[s]

    def landmark_points(self, alpha: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
        """(88, 3) model-space landmark positions with the current correspondences."""
        p = self.points(alpha, delta)
        return (1 - self.t)[:, None] * p[self.rows_a] + self.t[:, None] * p[self.rows_b]

    def projected(self, rotation: torch.Tensor, translation: torch.Tensor, alpha: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
        """(88, 2) projected landmarks with the current correspondences."""
        return project(self.landmark_points(alpha, delta), rotation, translation, self.camera)

    def residuals(self, rotation: torch.Tensor, translation: torch.Tensor, alpha: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
        """(176,) weighted landmark residuals; Σ r² = L_lan."""
        diff = self.projected(rotation, translation, alpha, delta) - self.targets
        return (diff * self.sqrt_w[:, None]).reshape(-1)

    def jacobian(self, rotation: torch.Tensor, translation: torch.Tensor, alpha: torch.Tensor, delta: torch.Tensor, n_id: int, n_exp: int, t_unit: float) -> torch.Tensor:
        """(176, 6 + n_id + n_exp) Jacobian of :meth:`residuals` with respect to the update
        x = (ω, Δt / t_unit, Δα[:n_id], Δδ[:n_exp]) of R·exp([ω]×), t + t_unit·Δt, α, δ at x = 0.

        Written out (chain rule through the pinhole projection) because torch.func.jacfwd costs
        about a second of tracing on the first call, more than the whole fit; a test checks it
        against jacfwd in float64."""
        p_model = self.landmark_points(alpha, delta)  # (88, 3)
        cam = p_model @ rotation.T + translation
        depth = (-cam[:, 2]).clamp_min(1e-6)
        f = self.camera.focal
        zero = torch.zeros_like(depth)
        # d(u, v) / d(x_c, y_c, z_c): (88, 2, 3)
        dproj = torch.stack(
            [
                torch.stack([f / depth, zero, f * cam[:, 0] / depth**2], dim=-1),
                torch.stack([zero, -f / depth, -f * cam[:, 1] / depth**2], dim=-1),
            ],
            dim=1,
        )
        px, py, pz = p_model.unbind(-1)
        z0 = torch.zeros_like(px)
        skew = torch.stack([z0, -pz, py, pz, z0, -px, -py, px, z0], dim=-1).reshape(-1, 3, 3)
        d_rot = -rotation @ skew  # (88, 3, 3): d X_c / d ω
        d_trans = (t_unit * torch.eye(3, dtype=cam.dtype)).expand(len(cam), 3, 3)

        def blend(basis: torch.Tensor) -> torch.Tensor:  # (k, K, 3) -> (k, 88, 3) on the slid edges
            return (1 - self.t)[None, :, None] * basis[:, self.rows_a] + self.t[None, :, None] * basis[:, self.rows_b]

        d_id = torch.einsum("ij,kvj->vik", rotation, blend(self.id_basis[:n_id]))  # (88, 3, n_id)
        d_exp = torch.einsum("ij,kvj->vik", rotation, blend(self.exp_basis[:n_exp]))
        d_cam = torch.cat([d_rot, d_trans, d_id, d_exp], dim=-1)  # (88, 3, n)
        return (torch.einsum("vab,vbn->van", dproj, d_cam) * self.sqrt_w[:, None, None]).reshape(2 * len(cam), -1)

    def correspondence(self) -> np.ndarray:
        """(88,) int64: the model vertex nearest to each (slid) landmark."""
        rows = torch.where(self.t < 0.5, self.rows_a, self.rows_b).numpy()
        return self.subset[rows]


def _levenberg_marquardt(problem: _LandmarkProblem, state: dict[str, torch.Tensor], stage: LandmarkStage) -> int:
    """Run ``stage.iterations`` damped Gauss–Newton steps on ``state`` (updated in place).

    The rotation is updated multiplicatively, R ← R·exp([ω]×), so ω is always near zero.
    Returns the number of accepted steps."""
    n_id = problem.model.n_id if stage.n_id is None else min(stage.n_id, problem.model.n_id)
    n_exp = problem.model.n_exp if stage.expression else 0
    lam_id, lam_exp = REGULARISATION["id"], REGULARISATION["exp"]
    t_unit = 10.0  # mm per unit of the translation parameter (keeps the system well scaled)

    def unpack(x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        rot = state["rotation"] @ rotation_from_axis_angle(x[:3])
        trans = state["translation"] + t_unit * x[3:6]
        alpha = torch.cat([state["alpha"][:n_id] + x[6 : 6 + n_id], state["alpha"][n_id:]])
        delta = torch.cat([state["delta"][:n_exp] + x[6 + n_id :], state["delta"][n_exp:]])
        return rot, trans, alpha, delta

    def all_residuals(x: torch.Tensor) -> torch.Tensor:
        rot, trans, alpha, delta = unpack(x)
        return torch.cat([problem.residuals(rot, trans, alpha, delta), lam_id**0.5 * alpha, lam_exp**0.5 * delta])

    n = 6 + n_id + n_exp
    damping, accepted = 1e-3, 0
    for _ in range(stage.iterations):
        problem.slide_jaw(state["rotation"], state["translation"], state["alpha"], state["delta"])
        x0 = torch.zeros(n, dtype=torch.float64)
        r0 = all_residuals(x0)
        jac_lm = problem.jacobian(state["rotation"], state["translation"], state["alpha"], state["delta"], n_id, n_exp, t_unit)
        jac_reg = torch.zeros(problem.model.n_id + problem.model.n_exp, n, dtype=torch.float64)
        jac_reg[range(n_id), range(6, 6 + n_id)] = lam_id**0.5
        rows = [problem.model.n_id + k for k in range(n_exp)]
        jac_reg[rows, range(6 + n_id, n)] = lam_exp**0.5
        jac = torch.cat([jac_lm, jac_reg])
        jtj, jtr = jac.T @ jac, jac.T @ r0
        cost0 = float(r0 @ r0)
        diag = torch.diagonal(jtj).clamp_min(1e-12)
        for _attempt in range(8):
            step = torch.linalg.solve(jtj + damping * torch.diag(diag), -jtr)
            r1 = all_residuals(step)
            cost1 = float(r1 @ r1)
            if torch.isfinite(r1).all() and cost1 < cost0:
                rot, trans, alpha, delta = unpack(step)
                state.update(rotation=rot, translation=trans, alpha=alpha, delta=delta)
                damping = max(damping / 3.0, 1e-7)
                accepted += 1
                break
            damping *= 4.0
        else:
            break  # no decrease possible: converged
        if cost0 - cost1 < CONVERGED_RELATIVE_DECREASE * cost0:
            break
    return accepted


def fit_landmarks(
    model: MorphableModel,
    landmarks: np.ndarray | torch.Tensor,
    camera: Camera,
    weights: np.ndarray | None = None,
    schedule: tuple[LandmarkStage, ...] = LANDMARK_SCHEDULE,
) -> Fit:
    """Fit pose, identity and expression to 88 given landmarks (no image).

    Args:
        model: the morphable model.
        landmarks: (88, 2) pixels (corner-origin); NaN rows are ignored.
        camera: the intrinsics of the image the landmarks come from.
        weights: (88,) per-point weights (default: :data:`LANDMARK_WEIGHTS`).
        schedule: the coarse-to-fine stages.
    Returns:
        A :class:`Fit` with β = 0 and γ = ambient white (no photometric stage).
    """
    targets = np.asarray(landmarks.detach().cpu().numpy() if isinstance(landmarks, torch.Tensor) else landmarks, dtype=np.float64)
    if targets.shape != (N_LANDMARKS, 2):
        raise InputError("<landmarks>", "landmarks", f"shape ({N_LANDMARKS}, 2) in pixels", str(targets.shape))
    valid = np.isfinite(targets).all(axis=1)
    if valid[17:68].sum() < 6:
        raise InputError("<landmarks>", "landmarks", "at least 6 finite non-jaw iBUG points", f"{int(valid[17:68].sum())}")
    weights = LANDMARK_WEIGHTS if weights is None else np.asarray(weights, dtype=np.float32)
    if weights.shape != (N_LANDMARKS,) or not np.all(np.isfinite(weights)) or np.any(weights < 0):
        raise InputError("<weights>", "weights", f"({N_LANDMARKS},) finite, non-negative", str(weights.shape))
    check_landmarks(targets, camera)

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    rotation, translation = _initial_pose(model, targets, camera)
    timings["pose_init"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    problem = _LandmarkProblem(model, targets, camera, weights)
    state = {
        "rotation": torch.tensor(rotation, dtype=torch.float64),
        "translation": torch.tensor(translation, dtype=torch.float64),
        "alpha": torch.zeros(model.n_id, dtype=torch.float64),
        "delta": torch.zeros(model.n_exp, dtype=torch.float64),
    }
    steps = {stage.name: _levenberg_marquardt(problem, state, stage) for stage in schedule}
    problem.slide_jaw(state["rotation"], state["translation"], state["alpha"], state["delta"])
    timings["landmarks"] = time.perf_counter() - t0
    return _assemble(model, problem, state, camera, targets, timings, {"landmark_steps": steps})


def _assemble(
    model: MorphableModel,
    problem: _LandmarkProblem,
    state: dict[str, torch.Tensor],
    camera: Camera,
    targets: np.ndarray,
    timings: dict[str, float],
    info: dict[str, Any],
) -> Fit:
    with torch.no_grad():
        fitted = problem.projected(state["rotation"], state["translation"], state["alpha"], state["delta"]).numpy()
        shape_vertices = model.shape(state["alpha"].float(), state["delta"].float())
        vertices = shape_vertices @ state["rotation"].float().T + state["translation"].float()
    errors = np.linalg.norm(fitted - targets, axis=1)
    valid = np.isfinite(errors)
    return Fit(
        alpha=state["alpha"].numpy().astype(np.float32),
        delta=state["delta"].numpy().astype(np.float32),
        beta=np.zeros(model.n_tex, dtype=np.float32),
        gamma=AMBIENT_WHITE.numpy().copy(),
        rotation=state["rotation"].numpy().astype(np.float32),
        translation=state["translation"].numpy().astype(np.float32),
        camera=camera,
        vertices=vertices.numpy().astype(np.float32),
        shape_vertices=shape_vertices.numpy().astype(np.float32),
        landmarks=targets.astype(np.float32),
        landmarks_fitted=fitted.astype(np.float32),
        landmark_vertices=problem.correspondence(),
        landmark_errors_px=errors.astype(np.float32),
        landmark_rms_px=float(np.sqrt(np.mean(errors[valid] ** 2))),
        timings=timings,
        info=info,
    )


# ---------------------------------------------------------------------------------- photometric
def skin_vertex_mask(model: MorphableModel) -> np.ndarray:
    """(V,) bool: the model's face region minus eyes (14 mm around iBUG 36–47), brows (9 mm
    around 17–26) and lips (8 mm around 48–67), measured on the mean shape."""
    mean = model.mean_shape
    keep = model.face_mask.copy()
    for points, radius in ((range(36, 48), 14.0), (range(17, 27), 9.0), (range(48, 68), 8.0)):
        centres = mean[model.landmark_indices[list(points)]]
        d2 = ((mean[:, None, :] - centres[None]) ** 2).sum(-1).min(axis=1)
        keep &= d2 > radius * radius
    return keep


def _sample_bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Colours (N, 3) of an (H, W, 3) float32 image at corner-origin pixel coordinates (N, 2)."""
    maps = (uv.astype(np.float32) - 0.5).reshape(-1, 1, 2)
    return cv2.remap(image, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3)


def _fit_photometric(model: MorphableModel, fit_result: Fit, image_linear: np.ndarray, rounds: int = 4) -> None:
    """Fit β and γ (in place on ``fit_result``) by alternating regularised least squares."""
    camera = fit_result.camera
    vertices = torch.from_numpy(fit_result.vertices)
    normals = model.vertex_normals(vertices).numpy()
    visible = vertex_visibility(fit_result.vertices, model.triangles, normals, camera)
    use = np.flatnonzero(visible & skin_vertex_mask(model))
    info: dict[str, Any] = {"visible_vertices": int(visible.sum()), "skin_vertices_used": int(len(use))}
    if len(use) < 50:
        info["skipped"] = "fewer than 50 visible skin vertices"
        fit_result.info["photometric"] = info
        return
    uv = project(fit_result.vertices[use].astype(np.float64), np.eye(3), np.zeros(3), camera)
    observed = torch.from_numpy(_sample_bilinear(image_linear, uv)).double()
    basis = sh_basis(torch.from_numpy(normals[use]).double())  # (N, 9)
    mean_albedo = model.tensor("mean_albedo", torch.float64)[use]
    tex_basis = model.tensor("tex_basis", torch.float64)[:, use] if model.n_tex else None
    beta = torch.zeros(model.n_tex, dtype=torch.float64)
    gamma = AMBIENT_WHITE.double().clone()
    inliers = torch.ones(len(use), dtype=torch.bool)
    sh_ridge = torch.full((N_SH,), REGULARISATION["sh"], dtype=torch.float64)
    sh_ridge[0] = 0.0
    for _ in range(rounds):
        albedo = mean_albedo if tex_basis is None else mean_albedo + torch.einsum("k,kvc->vc", beta, tex_basis)
        for c in range(3):  # γ given β: per channel ridge least squares
            a = albedo[inliers, c, None] * basis[inliers]
            gamma[c] = torch.linalg.solve(a.T @ a + torch.diag(sh_ridge) * len(a), a.T @ observed[inliers, c])
        if tex_basis is not None:  # β given γ: one ridge least squares over the 3 channels
            irr = basis @ gamma.T  # (N, 3)
            design = (tex_basis[:, inliers] * irr[inliers][None]).permute(1, 2, 0).reshape(-1, model.n_tex)
            rhs = (observed[inliers] - mean_albedo[inliers] * irr[inliers]).reshape(-1)
            reg = REGULARISATION["tex"] * len(rhs) * torch.eye(model.n_tex, dtype=torch.float64)
            beta = torch.linalg.solve(design.T @ design + reg, design.T @ rhs)
        albedo = mean_albedo if tex_basis is None else mean_albedo + torch.einsum("k,kvc->vc", beta, tex_basis)
        residual = (albedo * (basis @ gamma.T) - observed).norm(dim=1)
        sigma = 1.4826 * float(torch.median(residual[inliers])) + 1e-6
        inliers = residual < 3.0 * sigma
    info.update(inliers=int(inliers.sum()), rms_linear=float(residual[inliers].pow(2).mean().sqrt()))
    fit_result.beta = beta.numpy().astype(np.float32)
    fit_result.gamma = gamma.numpy().astype(np.float32)
    fit_result.info["photometric"] = info


def fit(
    image: np.ndarray | str | Path | Photo,
    model: MorphableModel | None = None,
    landmarks: np.ndarray | None = None,
    detector: str | LandmarkDetector = "hybrid",
    camera: Camera | None = None,
    photometric: bool = True,
) -> Fit:
    """Fit the model to one photo: landmarks (detected unless given), pose, shape, expression,
    then albedo and SH lighting.

    Args:
        image: (H, W, 3) uint8 RGB array, a path, or a loaded :class:`Photo`.
        model: the morphable model (default: :func:`load_model`'s default).
        landmarks: optional (88, 2) pixel landmarks in the image's coordinates.
        detector: a detector name (``hybrid``, ``dlib``, ``mediapipe``) or instance.
        camera: intrinsics (default: :meth:`Camera.for_image`, 40° field of view).
        photometric: run the albedo + lighting stage.
    """
    timings: dict[str, float] = {}
    notes: list[str] = []
    if isinstance(image, (str, Path)):
        t0 = time.perf_counter()
        image = load_photo(image)
        timings["load_image"] = time.perf_counter() - t0
    if isinstance(image, Photo):
        notes.extend(image.notes)
        source, pixels = image.path, image.image
    else:
        source, pixels = "<array>", as_rgb_uint8(image)
    t0 = time.perf_counter()
    model = load_model() if model is None else model
    timings["load_model"] = time.perf_counter() - t0
    height, width = pixels.shape[:2]
    camera = Camera.for_image(width, height) if camera is None else camera
    detection: FaceLandmarks | None = None
    if landmarks is None:
        t0 = time.perf_counter()
        det = get_detector(detector) if isinstance(detector, str) else detector
        detection = det.detect(pixels, source)
        landmarks = detection.points
        notes.extend(detection.notes)
        timings["detect"] = time.perf_counter() - t0
    result = fit_landmarks(model, landmarks, camera)
    result.timings = {**timings, **result.timings}
    if photometric:
        t0 = time.perf_counter()
        _fit_photometric(model, result, srgb_to_linear(pixels.astype(np.float32) / 255.0))
        result.timings["photometric"] = time.perf_counter() - t0
    result.info.update(
        source=source,
        model=model.name,
        detector=detection.detector if detection else "given",
        face_box=detection.box.tolist() if detection else None,
        faces_found=detection.n_faces if detection else None,
        notes=notes,
    )
    check_fit(result, image)
    return result
