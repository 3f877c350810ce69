"""One identity from several views of one person: the MAP landmark fit over a list of views, the
identity α shared by all of them, pose and expression δ per view.

A single photo does not carry enough evidence to tell a face from the model's average: a
detector's bias on a real face is about as large as the millimetre by which the face differs
from the mean (RESULTS.md, "Real head scans"). Several views of the same face see it from other
sides, and their landmark biases differ, so the identity they agree on is better determined than
any one view's. Averaging the separate single-view identities does not do it (a turned view's
identity is worse determined than a frontal one's, and an average weighs them alike); the views
are fitted jointly instead, each weighed by the landmark noise it shows.

The energy is the single-view one (:class:`~facegeo.fitting.priors.FitPriors`) summed over the
views, with one identity prior of precision c: E = Σ_k ‖r_k / σ_k‖² + c‖α‖² + Σ_k (‖δ_k / s‖² +
2 λ·δ_k), r_k the view's landmark residuals (:class:`~facegeo.fitting.landmark_problem.LandmarkProblem`,
in its own inter-ocular units) and σ_k its landmark noise, estimated per view from its residuals
(:func:`~facegeo.fitting.landmark_fit.solve_landmarks`'s noise model), so that a view whose
landmarks the model follows less closely weighs less. c = 1 is the exact MAP estimate for views
whose landmark errors are independent; a detector's errors on one face are not (its bias on the
person's features repeats from view to view), and the default c = the number of views counts the
views' evidence as one view's, averaged over them. Measured on renders of two real head scans
(five views, yaw 0°, ±20°, ±40°; benchmarks/bench_identity_views.py, RESULTS.md "One identity
from several views"), neutral shapes against the mean shape's error: c = 1 gives 1.05 and 1.12,
c = 5 0.78 and 1.01, where the mean of the five single-view identities gives 0.77 and 0.96 and
the best single view 0.81 and 0.70. The joint fit is the right machinery (with independent
landmark errors it beats every view and the average: tests/test_shared_identity.py), but with
today's detectors the views' biases do not cancel, and the landmarks alone do not beat the
average on real faces: what limits them is their bias, not the solver. Where every view has its
pixels, the landmark fit is then refined by the views' colours, which agree only where the
surface is the person's (:mod:`facegeo.fitting.view_consistency`: on the same renders 0.77 and
0.66).

It is minimised by the single-view fit's projected Levenberg–Marquardt over all parameters at
once; the normal equations have an arrow structure (each view's pose and δ couple only with α),
so each step eliminates the views' blocks first (the Schur complement onto α, as bundle
adjustment does) and costs O(views) rather than O(views³). Each view starts from its own
single-view solution, α from their mean.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from facegeo.camera import Camera
from facegeo.concurrency import numpy_blas_threads
from facegeo.errors import InputError, check_finite
from facegeo.forked_call import beside_child, can_fork, fork_call
from facegeo.fitting.landmark_fit import (CONVERGED_RELATIVE_DECREASE, LANDMARK_FIT_THREADS, NOISE_TOLERANCE, T_UNIT_MM,
                                          LandmarkPrior, LandmarkSolution, assemble_fit, damped_step, estimate_noise,
                                          rotation_step, solve_landmarks)
from facegeo.fitting.dense_term import DEFAULT_DENSE, DenseSettings
from facegeo.fitting.landmark_problem import LandmarkProblem, SurfacePoints
from facegeo.fitting.photo_fit import PhotoObservation, finish_photo_fit, observe_photo
from facegeo.fitting.priors import DEFAULT_PRIORS, LANDMARK_SCHEDULE, FitPriors
from facegeo.fitting.view_consistency import DEFAULT_CONSISTENCY, ConsistencySettings, refine_identity
from facegeo.landmarks.face_identity import SAME_PERSON_DISTANCE, face_descriptor, odd_ones_out
from facegeo.model_files import load_model
from facegeo.morphable_model import MorphableModel

if TYPE_CHECKING:
    from facegeo.fitting.result import Fit
    from facegeo.landmarks.detectors import LandmarkDetector
    from facegeo.photo import Photo

__all__ = ["LandmarkView", "solve_shared_identity", "fit_photos", "fit_observed"]


@dataclass(frozen=True)
class LandmarkView:
    """What one view contributes: ``landmarks`` (88, 2) px (NaN rows ignored), the view's
    ``camera``, ``weights`` (88,) relative precisions (None: the default), any dense
    ``surface_points`` (:class:`SurfacePoints`), the ``source`` its errors name (a photo's path)
    and its ``pixels`` (H, W, 3) uint8 RGB (None: the views' colours are not compared,
    :mod:`facegeo.fitting.view_consistency`)."""

    landmarks: np.ndarray
    camera: Camera
    weights: np.ndarray | None = None
    surface_points: SurfacePoints | None = None
    source: str = "<view>"
    pixels: np.ndarray | None = None

    @classmethod
    def of(cls, seen: PhotoObservation, source: str | None = None) -> LandmarkView:
        """The view of an observed photo (:func:`~facegeo.fitting.photo_fit.observe_photo`): its
        landmarks, camera, weights and dense points; ``source`` (default: the photo's) for errors."""
        return cls(seen.landmarks, seen.camera, seen.weights, seen.surface_points, seen.source if source is None else source,
                   seen.pixels if seen.pixels.size else None)  # a tracked frame's observation keeps no pixels


def solve_shared_identity(model: MorphableModel, views: Sequence[LandmarkView], priors: FitPriors = DEFAULT_PRIORS,
                          iterations: int | None = None, identity_precision: float | None = None,
                          consistency: ConsistencySettings | None = DEFAULT_CONSISTENCY) -> list[LandmarkSolution]:
    """Fit one identity α to several views of one face, pose and δ per view (module docstring).

    Args:
        model: the morphable model.
        views: one :class:`LandmarkView` per photo or frame (at least one).
        priors: the priors and the landmark noise model, as for a single view.
        iterations: Levenberg–Marquardt iterations of each joint round (default: the single-view
            schedule's last stage's).
        identity_precision: c, the identity prior's precision (module docstring; None: the
            number of views).
        consistency: the settings of the refinement by the views' colours
            (:func:`~facegeo.fitting.view_consistency.refine_identity`), made when every view has
            its ``pixels``; None: the landmark fit alone.
    Returns:
        One :class:`LandmarkSolution` per view, in order: their fits share ``alpha`` (and so
        ``shape_vertices`` up to the view's δ); each fit's ``info["shared_identity"]`` records the
        views, the per-view landmark noise (inter-ocular fraction) and the joint steps, and
        ``info["single_view"]`` the view's own single-view landmark RMS (px) for comparison.
    Raises:
        InputError: no views, or a view's landmarks the single-view fit refuses (naming the view's
            ``source``).
    """
    if not views:
        raise InputError("<views>", "views", "at least one view", "none")
    start = time.perf_counter()
    singles = []
    for k, view in enumerate(views):
        try:
            singles.append(solve_landmarks(model, view.landmarks, view.camera, view.weights, priors=priors,
                                           surface_points=view.surface_points))
        except InputError as error:
            raise type(error)(view.source, error.field, error.expected, error.found) from None
    if len(views) == 1:
        return singles
    prior = LandmarkPrior(model, priors)
    problems = [s.problem for s in singles]
    noises = [s.noise for s in singles]
    alpha = np.mean([s.fit.alpha.astype(np.float64) for s in singles], axis=0)
    states = [{"rotation": s.fit.rotation.astype(np.float64), "translation": s.fit.translation.astype(np.float64),
               "alpha": alpha, "delta": prior.project(s.fit.delta.astype(np.float64))} for s in singles]
    iterations = LANDMARK_SCHEDULE[-1].iterations if iterations is None else iterations
    identity_precision = float(len(views)) if identity_precision is None else float(identity_precision)
    if not (np.isfinite(identity_precision) and identity_precision > 0):
        raise InputError("<views>", "identity_precision", "a finite number > 0", repr(identity_precision))
    steps, history = [], [list(noises)]
    with numpy_blas_threads(LANDMARK_FIT_THREADS):
        for round_ in range(priors.noise_rounds + 1):
            if round_ > 0:
                estimates = [max(estimate_noise(p, st, prior, n)[0], priors.noise_floor) for p, st, n in zip(problems, states, noises)]
                if all(abs(np.log(e / n)) < NOISE_TOLERANCE for e, n in zip(estimates, noises)):
                    break
                noises = estimates
                history.append(list(noises))
            alpha = _joint_levenberg_marquardt(problems, states, alpha, prior, noises,
                                               iterations if round_ == 0 else max(iterations // 2, 1), steps, identity_precision)
        refined = None
        if consistency is not None and all(view.pixels is not None for view in views):
            for problem, state in zip(problems, states):
                problem.slide(state["rotation"], state["translation"], alpha, state["delta"])
            refined = refine_identity(model, [view.pixels for view in views], [view.camera for view in views], problems, states,
                                      noises, identity_precision, consistency)
            alpha = states[0]["alpha"]
        for problem, state in zip(problems, states):
            problem.slide(state["rotation"], state["translation"], alpha, state["delta"])
    seconds = time.perf_counter() - start
    solutions = []
    for k, (single, problem, state, noise) in enumerate(zip(singles, problems, states, noises)):
        info = dict(single.fit.info)
        info["landmark_noise"] = {**info["landmark_noise"], "iod_fraction": noise, "px": noise * problem.scale}
        info["shared_identity"] = {"views": len(views), "view": k + 1, "joint_steps": steps, "identity_precision": identity_precision,
                                   "noise_iod_fraction": [float(n) for n in noises],
                                   "noise_history_iod_fraction": [[float(n) for n in h] for h in history],
                                   "view_consistency": refined}
        info["single_view"] = {"landmark_rms_px": single.fit.landmark_rms_px,
                               "alpha_distance_sigma": float(np.linalg.norm(single.fit.alpha - alpha))}
        timings = {**single.fit.timings, "shared_identity": seconds}
        fit = assemble_fit(model, problem, state, views[k].camera, np.asarray(views[k].landmarks, np.float64), timings, info)
        check_finite({f"view {k + 1} fit {name}": getattr(fit, name) for name in ("rotation", "translation", "alpha", "delta",
                                                                                "vertices", "landmark_rms_px")}, views[k].source)
        solutions.append(LandmarkSolution(fit, problem, noise, prior.exp_scale, prior.exp_rate))
    return solutions


def _descriptors(seen: Sequence[PhotoObservation]) -> list[np.ndarray]:
    """Each observed photo's dlib face descriptor (128,) float32 (:func:`face_descriptor`)."""
    return [face_descriptor(s.pixels, s.landmarks) for s in seen]


def _joint_levenberg_marquardt(problems: list[LandmarkProblem], states: list[dict[str, np.ndarray]], alpha: np.ndarray,
                               prior: LandmarkPrior, noises: list[float], iterations: int, steps: list[int],
                               identity_precision: float) -> np.ndarray:
    """``iterations`` damped Gauss–Newton steps on the joint energy (module docstring; the
    identity prior's precision ``identity_precision``), every view's pose and δ and the shared α
    at once; updates ``states`` in place (each state's
    ``alpha`` is set to the new α) and returns α (n_id,) float64. Bounds on δ as the
    single-view step (:func:`~facegeo.fitting.landmark_fit._levenberg_marquardt`): weights at a
    bound whose gradient points outwards are held for the step, the step is projected. Appends
    the number of accepted steps to ``steps``."""
    model = problems[0].model
    n_id, n_exp = model.n_id, model.n_exp
    inv_var = prior.exp_scale**-2
    local_prior = np.concatenate([np.zeros(6), inv_var])

    def view_cost(problem: LandmarkProblem, state: dict, noise: float, a: np.ndarray) -> float:
        r = problem.residuals(state["rotation"], state["translation"], a, state["delta"]) / noise
        d = state["delta"]
        return float(r @ r + (d * d) @ inv_var + 2.0 * (prior.exp_rate @ d))

    damping, accepted = 1e-3, 0
    for _ in range(iterations):
        blocks = []
        h_aa = identity_precision * np.eye(n_id)
        g_a = identity_precision * alpha
        cost0 = identity_precision * float(alpha @ alpha)
        for problem, state, noise in zip(problems, states, noises):
            problem.slide(state["rotation"], state["translation"], alpha, state["delta"])
            r = problem.residuals(state["rotation"], state["translation"], alpha, state["delta"]) / noise
            jac = problem.jacobian(state["rotation"], state["translation"], alpha, state["delta"], n_id, n_exp, T_UNIT_MM) / noise
            d = state["delta"]
            cost0 += float(r @ r + (d * d) @ inv_var + 2.0 * (prior.exp_rate @ d))
            a_part = jac[:, 6:6 + n_id]
            local = np.concatenate([jac[:, :6], jac[:, 6 + n_id:]], axis=1)
            h_kk = local.T @ local
            h_kk[np.diag_indices_from(h_kk)] += local_prior
            g_k = local.T @ r
            g_k[6:] += d * inv_var + prior.exp_rate
            free = np.ones(6 + n_exp, dtype=bool)
            free[6:] = ~(((d <= prior.lower + 1e-9) & (g_k[6:] > 0)) | ((d >= prior.upper - 1e-9) & (g_k[6:] < 0)))
            h_aa += a_part.T @ a_part
            g_a += a_part.T @ r
            blocks.append((h_kk[np.ix_(free, free)], (local.T @ a_part)[free], g_k[free], free))
        diag_a = np.maximum(np.diagonal(h_aa), 1e-12)

        def attempt(mu: float) -> tuple[float, tuple[np.ndarray, list[dict]]]:
            schur, rhs = h_aa + np.diag(mu * diag_a), -g_a
            eliminated = []
            for h_kk, h_ka, g_k, _ in blocks:
                solved = np.linalg.solve(h_kk + np.diag(mu * np.maximum(np.diagonal(h_kk), 1e-12)),
                                         np.concatenate([h_ka, g_k[:, None]], axis=1))
                x_a, x_g = solved[:, :-1], solved[:, -1]
                schur -= h_ka.T @ x_a
                rhs += h_ka.T @ x_g
                eliminated.append((x_a, x_g))
            d_alpha = np.linalg.solve(schur, rhs)
            trial_alpha = alpha + d_alpha
            trials = []
            cost1 = identity_precision * float(trial_alpha @ trial_alpha)
            for (x_a, x_g), (_, _, _, free), problem, state, noise in zip(eliminated, blocks, problems, states, noises):
                step = np.zeros(6 + n_exp)
                step[free] = -x_g - x_a @ d_alpha
                trial = {"rotation": state["rotation"] @ rotation_step(step[:3]),
                         "translation": state["translation"] + T_UNIT_MM * step[3:6],
                         "alpha": trial_alpha, "delta": prior.project(state["delta"] + step[6:])}
                cost1 += view_cost(problem, trial, noise, trial_alpha)
                trials.append(trial)
            return cost1, (trial_alpha, trials)

        found, cost1, damping = damped_step(attempt, cost0, damping)
        if found is None:
            break  # no decrease possible: converged
        alpha, trials = found
        for state, trial in zip(states, trials):
            state.update(trial)
        accepted += 1
        if cost0 - cost1 < CONVERGED_RELATIVE_DECREASE * cost0:
            break
    steps.append(accepted)
    for state in states:
        state["alpha"] = alpha
    return alpha


def fit_photos(
    images: Sequence[np.ndarray | str | Path | Photo],
    model: MorphableModel | None = None,
    detector: str | LandmarkDetector = "hybrid",
    cameras: Sequence[Camera | None] | None = None,
    photometric: bool = True,
    priors: FitPriors = DEFAULT_PRIORS,
    dense: DenseSettings | None = DEFAULT_DENSE,
) -> list[Fit]:
    """Fit several photos of one person: one identity from all of them, pose, expression and
    camera per photo (:func:`solve_shared_identity`), then each photo's albedo and light and the
    single-photo checks (:func:`~facegeo.fitting.photo_fit.finish_photo_fit`). A photo of
    someone else (dlib's face descriptor farther than ``SAME_PERSON_DISTANCE`` from the main
    person's: :func:`facegeo.landmarks.face_identity.odd_ones_out`) is left out, and every fit's
    notes name it.

    Args:
        images: the photos ((H, W, 3) uint8 RGB arrays, paths or :class:`Photo`), each with its
            own camera and size.
        model: the morphable model (default: :func:`load_model`'s default).
        detector: a detector name or instance, for every photo.
        cameras: one camera per photo (None entries, or None: the focal of an unknown lens,
            estimated per photo as :func:`facegeo.fit` does).
        photometric, priors, dense: as :func:`facegeo.fit`.
    Returns:
        One :class:`Fit` per photo of the main person, in order; all share ``alpha``;
        ``info["shared_identity"]["left_out"]`` lists the photos left out.
    Raises:
        InputError: no photos, a camera count that does not match, or a photo :func:`facegeo.fit`
            would refuse (naming that photo).
    """
    if not images:
        raise InputError("<photos>", "photos", "at least one photo", "none")
    if cameras is not None and len(cameras) != len(images):
        raise InputError("<photos>", "cameras", f"one per photo ({len(images)})", str(len(cameras)))
    model = load_model() if model is None else model
    seen = [observe_photo(image, model, None, detector, None if cameras is None else cameras[k], dense)
            for k, image in enumerate(images)]
    return fit_observed(seen, model, photometric, priors)


def fit_observed(seen: Sequence[PhotoObservation], model: MorphableModel, photometric: bool = True,
                 priors: FitPriors = DEFAULT_PRIORS) -> list[Fit]:
    """:func:`fit_photos` of photos already observed (:func:`~facegeo.fitting.photo_fit.observe_photo`,
    one :class:`PhotoObservation` each, in order): the other photos' people left out, the joint
    fit, each photo's albedo, light and checks."""
    solutions = None
    if len(seen) > 1:
        # the photos' face descriptors in a forked child while this process fits all the photos
        # jointly: with none of them someone else's (the usual case) that fit is the answer
        forking = can_fork()

        def joint() -> list[LandmarkSolution] | None:
            if not forking:  # the descriptors first: a photo of someone else is not fitted
                return None
            try:
                return solve_shared_identity(model, [LandmarkView.of(s) for s in seen], priors)
            except InputError:  # perhaps the photo of someone else: fitted again without the odd ones
                return None

        solutions, descriptors = beside_child(lambda: fork_call(_descriptors, seen) if forking else None, joint,
                                              lambda lost: _descriptors(seen))
        odd = odd_ones_out(descriptors)
    else:
        odd = []
    left_out = [f"{seen[k].source}: another person (face descriptor {distance:.2f} from the others', more than "
                f"{SAME_PERSON_DISTANCE:g}): left out" for k, distance in odd]
    others = {k for k, _ in odd}
    kept = [s for k, s in enumerate(seen) if k not in others]
    if solutions is None or odd:
        solutions = solve_shared_identity(model, [LandmarkView.of(s) for s in kept], priors)
    fits = [finish_photo_fit(s, solution, photometric) for s, solution in zip(kept, solutions)]
    for fit in fits:
        fit.info.setdefault("shared_identity", {})["left_out"] = [seen[k].source for k, _ in odd]
        fit.info["notes"] = list(fit.info.get("notes", [])) + left_out
    return fits
