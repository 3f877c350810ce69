"""The MAP landmark fit (:func:`fit_landmarks`): pose from solvePnP, then a bounded
Levenberg–Marquardt on pose, identity α and expression δ minimising

    E = L_lan + λ_id‖α‖² + λ_exp‖δ‖²,   L_lan = Σ w_i‖π(R·S_i + t) − q_i‖² / (Σ w_i · s²)

with the 88-point weights of :mod:`facegeo.landmarks.scheme` (plus any dense surface points,
:class:`~facegeo.fitting.landmark_problem.SurfacePoints`) and s the detected inter-ocular
distance (so E does not depend on the image resolution). Coarse to fine
(:data:`~facegeo.fitting.priors.LANDMARK_SCHEDULE`): pose only, then pose + the first identity
components + expression, then everything; the landmark noise is re-estimated between rounds
(:class:`~facegeo.fitting.priors.FitPriors`).

Axes and units: DESIGN.md, "Conventions" (mm, +Y up, camera looks down −Z); pixels as in :mod:`facegeo.camera`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from facegeo.array_namespace import is_tensor
from facegeo.camera import OPENCV_FROM_OPENGL, Camera
from facegeo.concurrency import numpy_blas_threads
from facegeo.errors import InputError, check_finite
from facegeo.fitting.checks import check_landmarks
from facegeo.fitting.landmark_problem import LandmarkProblem, SurfacePoints
from facegeo.fitting.priors import CORRECTIVES, DEFAULT_PRIORS, LANDMARK_SCHEDULE, FitPriors, LandmarkStage
from facegeo.fitting.result import Fit
from facegeo.landmarks.scheme import INNER_FACE, LANDMARK_WEIGHTS, N_LANDMARKS, OUTER_EYE_CORNERS, inter_ocular_distance
from facegeo.lighting import AMBIENT_WHITE
from facegeo.morphable_model import MorphableModel

if TYPE_CHECKING:
    import torch

__all__ = ["fit_landmarks", "solve_landmarks", "landmark_targets", "LandmarkSolution", "LandmarkPrior", "estimate_noise",
           "assemble_fit", "damped_step", "initial_pose", "T_UNIT_MM", "CONVERGED_RELATIVE_DECREASE", "NOISE_TOLERANCE",
           "LANDMARK_FIT_THREADS", "rotation_step"]

CONVERGED_RELATIVE_DECREASE = 1e-4
#: mm per unit of the translation parameter of a Levenberg–Marquardt step (keeps the system well scaled).
T_UNIT_MM = 10.0
#: The noise re-estimation stops once σ changes by less than this (relative, in log).
NOISE_TOLERANCE = 0.1


# ---------------------------------------------------------------------------------- pose init
def initial_pose(model: MorphableModel, targets: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(R (3,3), t (3,)) in OpenGL camera axes from solvePnP on the non-jaw iBUG points."""
    ids = INNER_FACE
    ok = np.isfinite(targets[ids]).all(axis=1)
    obj = model.mean_shape[model.landmark_indices[ids[ok]]].astype(np.float64)
    img = targets[ids[ok]].astype(np.float64)
    K = camera.matrix()
    iod_model = inter_ocular_distance(model.mean_shape[model.landmark_indices])
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



def landmark_targets(landmarks: np.ndarray | torch.Tensor) -> np.ndarray:
    """The 88 landmarks (N_LANDMARKS, 2) px as float64 NumPy.

    Raises:
        InputError: any other shape."""
    targets = np.asarray(landmarks.detach().cpu().numpy() if is_tensor(landmarks) else landmarks, dtype=np.float64)
    if targets.shape != (N_LANDMARKS, 2):
        raise InputError("<landmarks>", "landmarks", f"shape ({N_LANDMARKS}, 2) in pixels", str(targets.shape))
    return targets


class LandmarkPrior:
    """The prior terms of E for one model and :class:`FitPriors`: scales, rates, bounds."""

    def __init__(self, model: MorphableModel, priors: FitPriors):
        blendshape = model.expression_kind == "blendshape"
        n_exp = model.n_exp
        self.exp_scale = np.full(n_exp, priors.expression_scale if blendshape else 1.0)
        self.exp_rate = np.full(n_exp, priors.expression_rate if blendshape else 0.0)
        lower, upper = model.expression_range
        self.lower, self.upper = lower.astype(np.float64), upper.astype(np.float64)
        names = list(model.expression_names)
        held = [names.index(n) for n in priors.held_expressions if n in names]
        self.lower[held] = self.upper[held] = 0.0
        for name, value in priors.measured_expressions:
            if name in names:
                k = names.index(name)
                self.lower[k] = self.upper[k] = float(np.clip(value, lower[k], upper[k]))
        self.correctives = [(names.index(c), names.index(d)) for c, d in CORRECTIVES.items() if c in names and d in names]

    def project(self, delta: np.ndarray) -> np.ndarray:
        """δ clipped into its range, each corrective at most its driver (a new array)."""
        delta = np.clip(delta, self.lower, self.upper)
        for c, d in self.correctives:
            delta[c] = min(delta[c], delta[d])
        return delta


def rotation_step(omega: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of the axis·angle vector ``omega`` (radians), by OpenCV's Rodrigues."""
    return cv2.Rodrigues(omega)[0]


def _levenberg_marquardt(problem: LandmarkProblem, state: dict[str, np.ndarray], stage: LandmarkStage, prior: LandmarkPrior,
                         noise: float) -> int:
    """Run ``stage.iterations`` damped Gauss–Newton steps on E (:class:`FitPriors`) for the
    landmark noise ``noise`` (inter-ocular units), updating ``state`` in place.

    The rotation is updated multiplicatively, R ← R·exp([ω]×), so ω is always near zero. Bounded
    expressions: a projected Levenberg–Marquardt step (Bertsekas' projected Newton): expression
    weights at a bound whose gradient points outwards are held there for the step, the others
    take the damped Gauss–Newton step, and the result is projected into the range (and each
    corrective below its driver). Projection was chosen over a smooth reparameterisation
    (δ = sigmoid(z)) because most weights of a real face sit exactly at 0, where a sigmoid's
    gradient vanishes and the weight can neither reach 0 nor leave it. Returns the number of
    accepted steps."""
    model = problem.model
    n_id = model.n_id if stage.n_id is None else min(stage.n_id, model.n_id)
    n_exp = model.n_exp if stage.expression else 0
    id_cols, exp_cols = slice(6, 6 + n_id), slice(6 + n_id, 6 + n_id + n_exp)
    inv_var = prior.exp_scale**-2

    def unpack(x: np.ndarray) -> tuple[np.ndarray, ...]:
        rot = state["rotation"] @ rotation_step(x[:3])
        trans = state["translation"] + T_UNIT_MM * x[3:6]
        alpha = state["alpha"].copy()
        alpha[:n_id] += x[id_cols]
        delta = state["delta"].copy()
        delta[:n_exp] += x[exp_cols]
        return rot, trans, alpha, prior.project(delta)

    def cost(rot: np.ndarray, trans: np.ndarray, alpha: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, float]:
        r = problem.residuals(rot, trans, alpha, delta) / noise
        return r, float(r @ r + alpha @ alpha + (delta * delta) @ inv_var + 2.0 * (prior.exp_rate @ delta))

    n = 6 + n_id + n_exp
    prior_precision = np.concatenate([np.zeros(6), np.ones(n_id), inv_var[:n_exp]])
    damping, accepted = 1e-3, 0
    for iteration in range(stage.iterations):
        if stage.slides is None or iteration < stage.slides:
            problem.slide(state["rotation"], state["translation"], state["alpha"], state["delta"])
        r0, cost0 = cost(state["rotation"], state["translation"], state["alpha"], state["delta"])
        jac = problem.jacobian(state["rotation"], state["translation"], state["alpha"], state["delta"], n_id, n_exp, T_UNIT_MM) / noise
        # normal equations of the landmark residuals plus the (diagonal) priors; grad is half ∇E
        jtj = jac.T @ jac
        jtj[np.diag_indices(n)] += prior_precision
        grad = jac.T @ r0
        grad[id_cols] += state["alpha"][:n_id]
        grad[exp_cols] += state["delta"][:n_exp] * inv_var[:n_exp] + prior.exp_rate[:n_exp]
        free = np.ones(n, dtype=bool)
        if n_exp:  # the ε-active set of the bounds
            d, g_exp, eps = state["delta"][:n_exp], grad[exp_cols], 1e-9
            free[exp_cols] = ~(((d <= prior.lower[:n_exp] + eps) & (g_exp > 0)) | ((d >= prior.upper[:n_exp] - eps) & (g_exp < 0)))
        h, g = jtj[np.ix_(free, free)], grad[free]
        diag = np.maximum(np.diagonal(h), 1e-12)

        def attempt(mu: float) -> tuple[float, tuple[np.ndarray, ...]]:
            step = np.zeros(n)
            step[free] = np.linalg.solve(h + np.diag(mu * diag), -g)
            candidate = unpack(step)
            return cost(*candidate)[1], candidate

        found, cost1, damping = damped_step(attempt, cost0, damping)
        if found is None:
            break  # no decrease possible: converged
        rot, trans, alpha, delta = found
        state.update(rotation=rot, translation=trans, alpha=alpha, delta=delta)
        accepted += 1
        if cost0 - cost1 < CONVERGED_RELATIVE_DECREASE * cost0:
            break
    return accepted


def damped_step(attempt: Callable[[float], tuple[float, Any]], cost0: float, damping: float) -> tuple[Any, float, float]:
    """Levenberg–Marquardt's search for a damping that lowers the cost: ``attempt(damping)``
    returns (the cost, the candidate) of the step solved with that damping; up to 8 attempts,
    the damping ×4 after each that does not lower ``cost0`` and ÷3 (at least 1e-7) after the one
    that does. Returns (candidate, its cost, the damping for the next step), or (None, inf, the
    raised damping) when none lowered the cost (converged)."""
    for _attempt in range(8):
        cost1, candidate = attempt(damping)
        if np.isfinite(cost1) and cost1 < cost0:
            return candidate, cost1, max(damping / 3.0, 1e-7)
        damping *= 4.0
    return None, float("inf"), damping


def estimate_noise(problem: LandmarkProblem, state: dict[str, np.ndarray], prior: LandmarkPrior, noise: float) -> tuple[float, float]:
    """(σ, p_eff): the landmark noise re-estimated from the residuals (:class:`FitPriors`)."""
    model = problem.model
    problem.slide(state["rotation"], state["translation"], state["alpha"], state["delta"])
    r = problem.residuals(state["rotation"], state["translation"], state["alpha"], state["delta"])
    jac = problem.jacobian(state["rotation"], state["translation"], state["alpha"], state["delta"], model.n_id, model.n_exp, T_UNIT_MM)
    d = state["delta"]
    free = np.ones(jac.shape[1], dtype=bool)
    free[6 + model.n_id :] = (d > prior.lower + 1e-9) & (d < prior.upper - 1e-9)
    a = jac[:, free]
    data = a.T @ a / noise**2
    precision = np.concatenate([np.zeros(6), np.ones(model.n_id), prior.exp_scale**-2])[free]
    p_eff = float(np.trace(np.linalg.solve(data + np.diag(precision), data)))
    n_obs = 2 * problem.n_observations - problem.n_sliding
    return float(np.sqrt(float(r @ r) / max(n_obs - p_eff, 1.0))), p_eff


@dataclass(frozen=True)
class LandmarkSolution:
    """What :func:`solve_landmarks` ends with: the ``fit``, its landmark ``problem`` (slid at the
    final state), the landmark ``noise`` σ (inter-ocular units) and the δ prior's per-weight
    ``expression_scale`` and ``expression_rate`` (n_exp,): what a later stage that keeps the
    landmark term (:mod:`facegeo.fitting.shading_refine`) needs."""

    fit: Fit
    problem: LandmarkProblem
    noise: float
    expression_scale: np.ndarray
    expression_rate: np.ndarray


def fit_landmarks(
    model: MorphableModel,
    landmarks: np.ndarray | torch.Tensor,
    camera: Camera,
    weights: np.ndarray | None = None,
    schedule: tuple[LandmarkStage, ...] = LANDMARK_SCHEDULE,
    priors: FitPriors = DEFAULT_PRIORS,
    init: Fit | None = None,
    surface_points: SurfacePoints | None = None,
) -> Fit:
    """The MAP landmark fit: :func:`solve_landmarks`'s ``fit`` (same arguments, documented there)."""
    return solve_landmarks(model, landmarks, camera, weights, schedule, priors, init, surface_points).fit


def solve_landmarks(
    model: MorphableModel,
    landmarks: np.ndarray | torch.Tensor,
    camera: Camera,
    weights: np.ndarray | None = None,
    schedule: tuple[LandmarkStage, ...] = LANDMARK_SCHEDULE,
    priors: FitPriors = DEFAULT_PRIORS,
    init: Fit | None = None,
    surface_points: SurfacePoints | None = None,
) -> Fit:
    """Fit pose, identity and expression to 88 given landmarks (no image): the MAP estimate of
    :class:`FitPriors`, with expression weights inside the model's range.

    Args:
        model: the morphable model.
        landmarks: (88, 2) pixels (corner-origin); NaN rows are ignored.
        camera: the intrinsics of the image the landmarks come from.
        weights: (88,) per-point relative precisions (default: :data:`LANDMARK_WEIGHTS`).
        schedule: the coarse-to-fine stages (the last one is repeated after each noise update).
        priors: the priors and the landmark noise model.
        init: start from this fit's pose, α and δ (e.g. a regressor's prediction; δ is clipped
            into the model's range) instead of solvePnP on the mean shape.
        surface_points: dense points on the model surface observed beside the 88
            (:func:`facegeo.fitting.dense_term.dense_surface_points`), or None.
    Returns:
        A :class:`Fit` with β = 0 and γ = ambient white (no photometric stage);
        ``info["landmark_noise"]`` holds the estimated noise (px and inter-ocular fraction),
        the effective number of parameters and the expression weights held at a bound.
    """
    targets = landmark_targets(landmarks)
    valid = np.isfinite(targets).all(axis=1)
    weights = LANDMARK_WEIGHTS if weights is None else np.asarray(weights, dtype=np.float32)
    if weights.shape != (N_LANDMARKS,):
        raise InputError("<weights>", "weights", f"shape ({N_LANDMARKS},)", str(weights.shape))
    if not np.all(np.isfinite(weights) & (weights >= 0)):
        bad = np.flatnonzero(~(np.isfinite(weights) & (weights >= 0)))
        raise InputError("<weights>", "weights", "finite, non-negative values",
                         f"{len(bad)} of {N_LANDMARKS} NaN, infinite or negative (first at point {bad[0]})")
    used = valid & (weights > 0)
    if used[INNER_FACE].sum() < 6:
        raise InputError("<landmarks>", "landmarks", "at least 6 finite non-jaw iBUG points of positive weight",
                         f"{int(used[INNER_FACE].sum())}")
    if not valid[OUTER_EYE_CORNERS].all():  # their distance is the fit's scale and the RMS's unit
        missing = ", ".join(str(i) for i in OUTER_EYE_CORNERS[~valid[OUTER_EYE_CORNERS]])
        raise InputError("<landmarks>", "landmarks", "finite outer eye corners (iBUG 36 and 45: the fit's scale)",
                         f"NaN or infinite at point {missing}")
    check_landmarks(targets, camera)

    with numpy_blas_threads(LANDMARK_FIT_THREADS):
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        prior = LandmarkPrior(model, priors)
        if init is None:
            rotation, translation = initial_pose(model, targets, camera)
            alpha, delta = np.zeros(model.n_id), np.zeros(model.n_exp)
        else:
            rotation, translation, alpha, delta = init.rotation, init.translation, init.alpha, init.delta
        timings["pose_init"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        problem = LandmarkProblem(model, targets, camera, weights, surface_points, priors.brow_along_noise)
        state = {
            "rotation": np.array(rotation, dtype=np.float64),
            "translation": np.array(translation, dtype=np.float64),
            "alpha": np.array(alpha, dtype=np.float64),
            "delta": prior.project(np.array(delta, dtype=np.float64)),
        }
        noise = priors.noise
        steps = {stage.name: _levenberg_marquardt(problem, state, stage, prior, noise) for stage in schedule[:-1]}
        history = [noise]
        p_eff: float | None = None  # not estimated: the noise was given (one stage, no noise rounds)
        last = schedule[-1]
        for round_ in range(priors.noise_rounds + 1):
            if round_ > 0 or len(schedule) > 1:  # the noise is estimated once some shape is fitted
                estimate, p_eff = estimate_noise(problem, state, prior, noise)
                estimate = max(estimate, priors.noise_floor)
                if round_ > 0 and abs(np.log(estimate / noise)) < NOISE_TOLERANCE:
                    break
                noise = estimate
                history.append(noise)
            stage = last if round_ == 0 else LandmarkStage(last.name, max(last.iterations // 2, 1), last.n_id, last.expression)
            steps[f"{last.name}@{noise:.4f}"] = _levenberg_marquardt(problem, state, stage, prior, noise)
        problem.slide(state["rotation"], state["translation"], state["alpha"], state["delta"])
        timings["landmarks"] = time.perf_counter() - t0
    d = state["delta"]
    info = {
        "landmark_steps": steps,
        "landmark_noise": {
            "iod_fraction": noise,
            "px": noise * problem.scale,
            "history_iod_fraction": history,
            "effective_parameters": p_eff,
            "expression_at_lower": int(((d <= prior.lower + 1e-9) & np.isfinite(prior.lower)).sum()),
            "expression_at_upper": int(((d >= prior.upper - 1e-9) & np.isfinite(prior.upper)).sum()),
        },
    }
    if not valid.all():
        left_out = np.flatnonzero(~valid)
        info["notes"] = [f"{len(left_out)} of {N_LANDMARKS} landmarks NaN or infinite, left out of the fit and of its RMS: "
                         f"point{'s' if len(left_out) > 1 else ''} {', '.join(map(str, left_out))}"]
    result = assemble_fit(model, problem, state, camera, targets, timings, info)
    # never a NaN out of the public API: a solve that diverged is refused, naming what went wrong
    check_finite({f"fit {name}": getattr(result, name) for name in ("rotation", "translation", "alpha", "delta", "vertices",
                                                                     "landmarks_fitted", "landmark_rms_px")}, "<landmarks>")
    return LandmarkSolution(result, problem, noise, prior.exp_scale, prior.exp_rate)


#: BLAS threads for the landmark fit's small (176 × ~160) linear algebra: on a loaded 2-core
#: machine more threads made it 5–15× slower for identical results (benchmarks/bench_fit_speed.py,
#: results in benchmarks/RESULTS.md).
LANDMARK_FIT_THREADS = 1


def assemble_fit(
    model: MorphableModel,
    problem: LandmarkProblem,
    state: dict[str, np.ndarray],
    camera: Camera,
    targets: np.ndarray,
    timings: dict[str, float],
    info: dict[str, Any],
) -> Fit:
    """The :class:`Fit` of a solved landmark problem: ``state`` (rotation (3, 3), translation (3,)
    mm, alpha (n_id,), delta (n_exp,), float64) posed in ``camera``, the 88 ``targets`` (px) and
    their errors (px; the RMS over the points the fit used), ``timings`` and ``info`` as given.
    Shared by the single-view fit and the fit of several views (:mod:`facegeo.fitting.shared_identity`)."""
    projected = problem.projected(state["rotation"], state["translation"], state["alpha"], state["delta"])
    fitted = projected[:N_LANDMARKS]
    if problem.n_points > N_LANDMARKS:  # the surface points' residuals, px
        dense_errors = np.linalg.norm(projected[N_LANDMARKS:] - problem.targets[N_LANDMARKS:], axis=1)
        used = problem.sqrt_w[N_LANDMARKS:] > 0
        # each point's noise σ_i = σ / √w_i (px), the landmark noise σ over its relative precision
        w = (problem.sqrt_w[N_LANDMARKS:] * problem.scale) ** 2
        sigma = info["landmark_noise"]["px"] / np.sqrt(np.maximum(w, 1e-12))
        info["surface_points"] = {"used": int(used.sum()),
                                  "rms_px": float(np.sqrt(np.mean(dense_errors[used] ** 2))) if used.any() else None,
                                  "sigma_px": [round(float(x), 3) if u else None for x, u in zip(sigma, used)],
                                  "residual_px": [round(float(x), 3) for x in dense_errors]}
    shape_vertices = model.shape_numpy(state["alpha"], state["delta"])
    rotation, translation = state["rotation"].astype(np.float32), state["translation"].astype(np.float32)
    vertices = shape_vertices @ rotation.T + translation
    errors = np.linalg.norm(fitted - targets, axis=1)
    valid = np.isfinite(errors) & (problem.sqrt_w[:N_LANDMARKS] > 0)  # the RMS is over the points the fit used
    return Fit(
        alpha=state["alpha"].astype(np.float32),
        delta=state["delta"].astype(np.float32),
        beta=np.zeros(model.n_tex, dtype=np.float32),
        gamma=AMBIENT_WHITE.copy(),
        rotation=rotation,
        translation=translation,
        camera=camera,
        vertices=vertices.astype(np.float32),
        shape_vertices=shape_vertices.astype(np.float32),
        landmarks=targets.astype(np.float32),
        landmarks_fitted=fitted.astype(np.float32),
        landmark_vertices=problem.correspondence(),
        landmark_errors_px=errors.astype(np.float32),
        landmark_rms_px=float(np.sqrt(np.mean(errors[valid] ** 2))),
        timings=timings,
        info=info,
    )

