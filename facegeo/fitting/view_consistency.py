"""Several views of one face agree on its colours where they see the same surface: the shared
identity refined by that agreement (photometric consistency between views).

A detector's landmarks are biased on a real face, and the bias repeats from view to view, so the
landmark fit of several views (:mod:`facegeo.fitting.shared_identity`) does not average it out.
The views' pixels carry what the landmarks miss: where the identity (the face's shape) and the
views' poses are right, one surface point lands on the same skin in every view that sees it
(its mole, pores, stubble, the edge of a brow or a nostril), and a wrong depth or width moves it
to other skin in a turned view. Multi-view stereo minimises the disagreement over a dense surface;
here the surface is the model's, so the disagreement is minimised over its identity α and the
views' poses, with the views' landmark energy and the identity prior kept (the expressions δ
stay as the landmark fit left them: free, they would absorb the disagreement per view).

For every pair of views, each vertex of the front of the face (:data:`REGIONS`; ``points`` of
them at random, the same in every view) that both see (facing each camera at ``min_facing`` or
more, not hidden, at the landmark fit's pose) gives the difference of the two views' colours
where it projects (bilinear, on the views' photos blurred by a Gaussian of σ inter-ocular
distances; coarse to fine), over the pair's robust spread of that difference, under a
Charbonnier loss (ρ(x) = √(1 + x²) − 1: quadratic near 0, linear for what no shape explains, such
as a specular highlight, an eye that looks elsewhere or hair). One colour gain per pair and
channel (the ratio of the pair's median colours) takes out a difference in exposure or white
balance. A pair's term is its mean loss over its points times ``weight``: the points' errors are
not independent (the blur and the model's own errors correlate them), so a pair counts as a fixed
amount of evidence whatever the photo's resolution. The energy

    E = Σ_k ‖r_k / σ_k‖² + c‖α‖² + Σ_(i,j) weight · mean_p Σ_channel ρ((g_ij c_i(p) − c_j(p)) / s_ij)

(r_k the view's landmark residuals and σ_k its noise, as in the joint landmark fit) is minimised
by Levenberg–Marquardt with iteratively reweighted Gauss–Newton steps for ρ; the colours'
derivatives are the blurred photos' central differences at the projected points. Written by hand:
no library fits a morphable model's coefficients to several photos' colour agreement.

Measured on renders of two real head scans (benchmarks/RESULTS.md, "the views' colours"): from
five views (yaw 0°, ±20°, ±40°) the neutral identity's error over the mean shape's goes from 0.78
to 0.77 (James) and from 1.01 to 0.66 (Lee Perry-Smith); from a rendered head-turn clip's five
keyframes from 0.73 to 0.80 and from 0.94 to 0.62. It costs about 0.8 s for five views.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from facegeo.camera import Camera, cross_matrices, pixels_jacobian, to_pixels
from facegeo.fitting.landmark_fit import T_UNIT_MM, damped_step, rotation_step
from facegeo.fitting.landmark_problem import LandmarkProblem
from facegeo.morphable_model import MorphableModel
from facegeo.normals import vertex_normals
from facegeo.skin_mask import vertex_regions
from facegeo.visibility import vertex_visibility

__all__ = ["ConsistencySettings", "DEFAULT_CONSISTENCY", "refine_identity"]


@dataclass(frozen=True)
class ConsistencySettings:
    """The photometric refinement's knobs (module docstring).

    Attributes:
        weight: each pair of views' term, its mean Charbonnier loss over its points times this
            (the landmark energy of a view is ~10² at its noise).
        blur_iod: the Gaussian σ of each level, coarse to fine, in inter-ocular distances of the
            view (at a 90 px inter-ocular distance 4, 2 and 1 px).
        iterations: Levenberg–Marquardt steps at most per level.
        min_facing: a vertex counts in a view whose camera it faces at least at this cosine.
        points: at most this many of the face's vertices (an even random subset, the same in every
            view; 0: all; else ≥ 100).
        converged: a level ends when a step lowers the energy by less than this fraction.
    """

    weight: float = 200.0
    blur_iod: tuple[float, ...] = (0.045, 0.022, 0.011)
    iterations: int = 15
    min_facing: float = 0.3
    points: int = 2500
    converged: float = 1e-2

    def __post_init__(self) -> None:
        checks = {"weight": np.isfinite(self.weight) and self.weight > 0,
                  "blur_iod": len(self.blur_iod) > 0 and all(np.isfinite(b) and b > 0 for b in self.blur_iod),
                  "iterations": self.iterations >= 1, "min_facing": 0.0 <= self.min_facing < 1.0,
                  "points": self.points == 0 or self.points >= 100, "converged": np.isfinite(self.converged) and self.converged > 0}
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f"ConsistencySettings.{name}: {getattr(self, name)!r} is out of range")


DEFAULT_CONSISTENCY = ConsistencySettings()
#: The face's regions (:func:`facegeo.skin_mask.vertex_regions`) whose vertices are compared: the
#: front of the face, not the eyes (an eye looks elsewhere in each photo, its lashes and the
#: eyeball's shine move with the view) nor the head's sides (ears, hair, the jaw under a beard,
#: where the model's surface is not the person's). Measured before the last speed-ups (three
#: levels to 1e-4): on the scans' five views, with the eyes 0.78 and 0.63 of the mean shape's
#: error, without them 0.76 and 0.65; from the head-turn clip 0.89 and 0.58 with, 0.82 and 0.62
#: without (benchmarks/RESULTS.md, "the views' colours").
REGIONS = ("forehead", "nose", "cheeks", "chin", "lips", "brows")


def refine_identity(model: MorphableModel, pixels: Sequence[np.ndarray], cameras: Sequence[Camera], problems: Sequence[LandmarkProblem],
                    states: Sequence[dict[str, np.ndarray]], noises: Sequence[float], identity_precision: float,
                    settings: ConsistencySettings = DEFAULT_CONSISTENCY) -> dict:
    """Refine the shared identity and the views' poses by the views' colour agreement (module
    docstring), from the joint landmark fit's solution.

    Args:
        model: the morphable model.
        pixels: per view its photo (H, W, 3) uint8 RGB.
        cameras: per view its camera.
        problems: per view its landmark problem (:class:`LandmarkProblem`, slid to ``states``).
        states: per view ``rotation`` (3, 3), ``translation`` (3,) mm, ``alpha`` (n_id,) (the
            same in all) and ``delta`` (n_exp,), float64: updated in place (δ is held).
        noises: per view its landmark noise (inter-ocular fraction).
        identity_precision: c, the identity prior's precision.
        settings: the knobs.
    Returns:
        A report: per level its σ (inter-ocular fraction), steps and energy before and after, the
        pairs' points, the change of α (σ units) and the seconds taken.
    """
    start = time.perf_counter()
    k_views = len(states)
    regions = vertex_regions(model)
    samples = np.flatnonzero(model.face_mask & (np.max([regions[n] for n in REGIONS], axis=0) >= 0.5))
    if settings.points and len(samples) > settings.points:  # an even random subset, the same in every view
        samples = np.sort(np.random.default_rng(0).choice(samples, settings.points, replace=False))
    mean = model.mean_shape[samples].astype(np.float64)
    id_basis = model.id_basis[:, samples].astype(np.float64)  # (n_id, n, 3)
    n_id = model.n_id
    by_vertex = np.ascontiguousarray(id_basis.transpose(1, 2, 0), dtype=np.float32)  # (n, 3, n_id)
    n_params = n_id + 6 * k_views
    expression = [model.shape_numpy(None, st["delta"], samples).astype(np.float64) - mean for st in states]
    alpha0 = states[0]["alpha"].copy()

    def neutral(alpha: np.ndarray) -> np.ndarray:
        """(n, 3) mm: the sampled vertices of α's neutral face (each view adds its ``expression``)."""
        return mean + np.einsum("k,kvc->vc", alpha, id_basis)

    pairs, common = _pairs(model, samples, cameras, states, settings)
    if not pairs:
        return {"pairs": 0, "levels": [], "alpha_change": 0.0, "seconds": time.perf_counter() - start}
    crops = [_face_crop(image, camera, neutral(alpha0) + e, st, settings, problem.scale)
             for image, camera, st, e, problem in zip(pixels, cameras, states, expression, problems)]

    def landmarks(sts: Sequence[dict[str, np.ndarray]], alpha: np.ndarray, jacobian: bool):
        cost, blocks = 0.0, []
        for problem, st, noise in zip(problems, sts, noises):
            r = problem.residuals(st["rotation"], st["translation"], alpha, st["delta"]) / noise
            cost += float(r @ r)
            if jacobian:
                jac = problem.jacobian(st["rotation"], st["translation"], alpha, st["delta"], n_id, 0, T_UNIT_MM) / noise
                blocks.append((r, jac[:, :6], jac[:, 6:6 + n_id]))
        return cost, blocks

    levels = []
    for blur in settings.blur_iod:
        images = [crop.level(blur) for crop in crops]
        start_face = neutral(states[0]["alpha"])
        seen = [_Seen(image, cameras[k], states[k], start_face + expression[k], None) for k, image in enumerate(images)]
        gains, spreads = [], []
        for (i, j), points in zip(pairs, common):
            ci, cj = seen[i].colours[points], seen[j].colours[points]
            gain = np.median(cj, axis=0) / np.maximum(np.median(ci, axis=0), 1e-4)
            gains.append(gain)
            spreads.append(1.4826 * float(np.median(np.abs(ci * gain - cj))) + 1e-3)

        def pair_terms(views: list[_Seen], jacobian: bool) -> tuple[float, np.ndarray, np.ndarray]:
            """The pairs' cost, and their Gauss–Newton matrix and gradient."""
            cost, hessian, gradient = 0.0, np.zeros((n_params, n_params)), np.zeros(n_params)
            for (i, j), points, gain, spread in zip(pairs, common, gains, spreads):
                x = (views[i].colours[points] * gain - views[j].colours[points]) / spread  # (m, 3)
                scale = settings.weight / len(points)
                cost += scale * float((np.sqrt(1.0 + x * x) - 1.0).sum())
                if not jacobian:
                    continue
                # d x / d (alpha, pose_i, pose_j), (m, 3, n_id + 12), in float32 as the derivatives
                g = gain.astype(np.float32)[:, None]
                jac = np.concatenate([g * views[i].d_alpha[points] - views[j].d_alpha[points],
                                      g * views[i].d_pose[points], -views[j].d_pose[points]], axis=2)
                jac = jac.reshape(-1, jac.shape[2]) / np.float32(spread)
                w = 0.5 * scale / np.sqrt(1.0 + x.reshape(-1) ** 2)  # the reweighted Gauss–Newton weights of ρ
                cols = np.r_[0:n_id, n_id + 6 * i:n_id + 6 * i + 6, n_id + 6 * j:n_id + 6 * j + 6]
                hessian[np.ix_(cols, cols)] += jac.T @ (jac * w[:, None].astype(np.float32))
                gradient[cols] += jac.T.astype(np.float64) @ (w * x.reshape(-1))
            return cost, hessian, gradient

        def energy(sts: Sequence[dict[str, np.ndarray]], alpha: np.ndarray, jacobian: bool):
            base = neutral(alpha)
            views = [_Seen(images[k], cameras[k], sts[k], base + expression[k], by_vertex if jacobian else None) for k in range(k_views)]
            cost, hessian, gradient = pair_terms(views, jacobian)
            landmark_cost, blocks = landmarks(sts, alpha, jacobian)
            cost += landmark_cost
            cost += identity_precision * float(alpha @ alpha)
            if jacobian:
                hessian[:n_id, :n_id] += identity_precision * np.eye(n_id)
                gradient[:n_id] += identity_precision * alpha
                for k, (r, j_pose, j_alpha) in enumerate(blocks):
                    cols = np.r_[n_id + 6 * k:n_id + 6 * k + 6, 0:n_id]
                    jac = np.concatenate([j_pose, j_alpha], axis=1)
                    hessian[np.ix_(cols, cols)] += jac.T @ jac
                    gradient[cols] += jac.T @ r
            return cost, hessian, gradient

        alpha = states[0]["alpha"].copy()
        cost, hessian, gradient = energy(states, alpha, True)
        first, steps, damping = cost, 0, 1e-3
        for _ in range(settings.iterations):
            diagonal = np.maximum(np.diagonal(hessian), 1e-12)

            def attempt(mu: float, hessian=hessian, gradient=gradient, diagonal=diagonal, alpha=alpha):
                step = np.linalg.solve(hessian + np.diag(mu * diagonal), -gradient)
                trial = [{**st, "rotation": st["rotation"] @ rotation_step(step[n_id + 6 * k:n_id + 6 * k + 3]),
                          "translation": st["translation"] + T_UNIT_MM * step[n_id + 6 * k + 3:n_id + 6 * k + 6],
                          "alpha": alpha + step[:n_id]} for k, st in enumerate(states)]
                return energy(trial, trial[0]["alpha"], False)[0], trial

            found, new_cost, damping = damped_step(attempt, cost, damping)
            if found is None:
                break
            for st, trial in zip(states, found):
                st.update(trial)
            alpha = states[0]["alpha"]
            steps += 1
            decrease = cost - new_cost
            for problem, st in zip(problems, states):
                problem.slide(st["rotation"], st["translation"], alpha, st["delta"])
            cost, hessian, gradient = energy(states, alpha, True)
            if decrease < settings.converged * cost:
                break
        levels.append({"blur_iod": blur, "steps": steps, "energy_before": first, "energy_after": cost})
    return {"pairs": len(pairs), "points": [int(len(p)) for p in common], "levels": levels,
            "alpha_change": float(np.linalg.norm(states[0]["alpha"] - alpha0)), "seconds": time.perf_counter() - start}


def _pairs(model: MorphableModel, samples: np.ndarray, cameras: Sequence[Camera], states: Sequence[dict[str, np.ndarray]],
           settings: ConsistencySettings) -> tuple[list[tuple[int, int]], list[np.ndarray]]:
    """The pairs of views that see ≥ 100 of the same vertices ``samples``, and those (as indices
    into ``samples``), from the visibility at ``states``."""
    seen = []
    for camera, st in zip(cameras, states):
        posed = model.shape_numpy(st["alpha"], st["delta"]).astype(np.float64) @ st["rotation"].T + st["translation"]
        normals = vertex_normals(posed.astype(np.float32), model.triangles).astype(np.float64)
        seen.append(vertex_visibility(posed, model.triangles, normals, camera, max_side=1024, min_facing=settings.min_facing)[samples])
    pairs, common = [], []
    for i in range(len(states)):
        for j in range(i + 1, len(states)):
            both = np.flatnonzero(seen[i] & seen[j])
            if len(both) < 100:
                continue
            pairs.append((i, j))
            common.append(both)
    return pairs, common


class _FaceCrop:
    """A view's photo cut to its face (with a margin for the coarsest blur), as float32 RGB in
    [0, 1]; :meth:`level` blurs it by σ inter-ocular distances and gives its central differences."""

    def __init__(self, image: np.ndarray, origin: tuple[int, int], inter_ocular_px: float):
        self.image, self.origin, self.inter_ocular_px = image, origin, inter_ocular_px

    def level(self, blur_iod: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]:
        sigma = max(blur_iod * self.inter_ocular_px, 0.5)
        blurred = cv2.GaussianBlur(self.image, (0, 0), sigma)
        dx = cv2.Sobel(blurred, cv2.CV_32F, 1, 0, ksize=1, scale=0.5)
        dy = cv2.Sobel(blurred, cv2.CV_32F, 0, 1, ksize=1, scale=0.5)
        return blurred, dx, dy, self.origin


def _face_crop(image: np.ndarray, camera: Camera, shape: np.ndarray, state: dict[str, np.ndarray], settings: ConsistencySettings,
               inter_ocular_px: float) -> _FaceCrop:
    """``image`` (H, W, 3) uint8 cut to the box of the face vertices ``shape`` (n, 3) mm posed by
    ``state``, with a margin of 4 coarsest σ."""
    u, v = to_pixels(shape @ state["rotation"].T + state["translation"], camera).T
    margin = 4.0 * max(settings.blur_iod) * inter_ocular_px + 4.0
    h, w = image.shape[:2]
    x0, x1 = int(max(np.floor(u.min() - margin), 0)), int(min(np.ceil(u.max() + margin), w))
    y0, y1 = int(max(np.floor(v.min() - margin), 0)), int(min(np.ceil(v.max() + margin), h))
    if x1 <= x0 or y1 <= y0:
        x0, y0, x1, y1 = 0, 0, w, h
    return _FaceCrop(image[y0:y1, x0:x1].astype(np.float32) / 255.0, (x0, y0), inter_ocular_px)


class _Seen:
    """One view's colours at the posed face vertices, and (given the identity basis as (n, 3,
    k)) their derivatives: ``colours`` (n, 3); ``d_alpha`` (n, 3, k) and ``d_pose`` (n, 3, 6) (the
    rotation's axis-angle step on the right, then the translation in :data:`T_UNIT_MM`)."""

    def __init__(self, level: tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]], camera: Camera,
                 state: dict[str, np.ndarray], shape: np.ndarray, id_basis: np.ndarray | None):
        blurred, dx, dy, (x0, y0) = level
        rotation = state["rotation"]
        posed = shape @ rotation.T + state["translation"]
        u, v = to_pixels(posed, camera).T
        map_x, map_y = (u - x0).astype(np.float32), (v - y0).astype(np.float32)

        def sample(img: np.ndarray) -> np.ndarray:
            return cv2.remap(img, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3).astype(np.float64)

        self.colours = sample(blurred)
        if id_basis is None:
            return
        # the derivatives in float32: the Gauss–Newton matrix needs no more, and its products take half the time
        grad = np.stack([sample(dx), sample(dy)], axis=-1).astype(np.float32)  # (n, 3, 2): d colour / d (u, v)
        d_point = grad @ pixels_jacobian(posed, camera.focal).astype(np.float32)  # (n, 3, 3): d colour / d camera-space point
        rotation32 = rotation.astype(np.float32)
        skew = cross_matrices(shape.astype(np.float32))
        self.d_pose = np.concatenate([d_point @ (-rotation32 @ skew), d_point * np.float32(T_UNIT_MM)], axis=2)
        self.d_alpha = (d_point @ rotation32) @ id_basis  # (n, 3, 3) @ (n, 3, k)
