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

Axes and units: DESIGN.md, "Conventions" (mm, +Y up, camera looks down −Z); pixels as in :mod:`facegeo.camera`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np
import torch
from threadpoolctl import threadpool_limits

from facegeo.camera import OPENCV_FROM_OPENGL, Camera, euler_from_rotation, project
from facegeo.colour import srgb_to_linear
from facegeo.errors import InputError
from facegeo.fit_checks import check_fit, check_landmarks
from facegeo.landmarks.detectors import FaceLandmarks, LandmarkDetector, get_detector
from facegeo.landmarks.scheme import CHIN, INNER_FACE, LANDMARK_WEIGHTS, N_LANDMARKS, OUTER_EYE_CORNERS, inter_ocular_distance
from facegeo.lighting import AMBIENT_WHITE, N_SH, sh_basis
from facegeo.model_files import load_model
from facegeo.morphable_model import MorphableModel
from facegeo.photo import Photo, as_rgb_uint8, load_photo
from facegeo.skin_mask import skin_vertex_mask
from facegeo.uv.texels import sample_bilinear
from facegeo.visibility import vertex_visibility

__all__ = ["Fit", "Fitter", "fit", "fit_landmarks", "FitPriors", "DEFAULT_PRIORS", "LandmarkStage", "LANDMARK_SCHEDULE",
           "PHOTOMETRIC_REGULARISATION", "CORRECTIVES"]


@dataclass(frozen=True)
class LandmarkStage:
    """One coarse-to-fine stage: Levenberg–Marquardt ``iterations`` with the pose, the first
    ``n_id`` identity components (None: all) and, if ``expression``, all expression components."""

    name: str
    iterations: int
    n_id: int | None
    expression: bool


#: The documented coarse-to-fine schedule of the landmark stage (error against iterations in
#: benchmarks/RESULTS.md). The last stage is repeated after each re-estimation of the noise
#: level (:class:`FitPriors`).
LANDMARK_SCHEDULE: tuple[LandmarkStage, ...] = (
    LandmarkStage("pose", 6, 0, False),
    LandmarkStage("coarse", 6, 20, True),
    LandmarkStage("fine", 12, None, True),
)

#: A stage stops early once a step lowers E by less than this fraction (1e-6 instead changes the
#: 3-D error on the validation faces by < 1 % for 1.2–1.5× the time: benchmarks/RESULTS.md).
CONVERGED_RELATIVE_DECREASE = 1e-4
#: The noise re-estimation stops once σ changes by less than this (relative, in log).
NOISE_TOLERANCE = 0.1


@dataclass(frozen=True)
class FitPriors:
    """The priors of the MAP landmark fit and the landmark noise model.

    The landmark stage minimises the negative log posterior (times 2)

        E = Σ_i w_i ‖r_i‖² / σ² + ‖α‖² + Σ_k (δ_k / s_δ)² + 2 Σ_k δ_k / τ

    with r_i the landmark residual in inter-ocular units, w_i the relative precisions of
    :data:`LANDMARK_WEIGHTS` (mean 1 over the valid points), α ~ N(0, I) the model's identity prior,
    and for blendshape models (``MorphableModel.expression_kind == "blendshape"``) a truncated
    Gaussian × exponential prior on δ ∈ [0, 1]: the Gaussian bounds the magnitude (scale s_δ =
    ``expression_scale``), the exponential (rate 1/τ = ``expression_rate``) favours sparse
    weights (for δ ≥ 0 it is an L1 penalty). PCA expression models get their own prior N(0, I)
    and no bounds. σ is the landmark noise per coordinate, in inter-ocular units: it starts at
    ``noise`` and is re-estimated ``noise_rounds`` times from the residuals of the fit,
    σ² = Σ w_i ‖r_i‖² / (n_obs − p_eff) with p_eff the effective number of fitted parameters
    (the trace of the data part of the posterior precision times the posterior covariance;
    MacKay's evidence approximation), never below ``noise_floor``. So the priors weigh as much
    as the landmark noise the fit actually sees: little on landmarks that a model face explains
    exactly, much on a real detector's landmarks of a real face. Values chosen on the
    validation set of ``benchmarks/bench_fit_priors.py`` (curves in benchmarks/RESULTS.md).
    """

    noise: float = 0.03
    noise_floor: float = 0.002
    noise_rounds: int = 4
    expression_scale: float = 0.25
    expression_rate: float = 2.0

    def __post_init__(self) -> None:
        for name in ("noise", "noise_floor", "expression_scale"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError("<priors>", name, "a finite number > 0", repr(value))
        if not (np.isfinite(self.expression_rate) and self.expression_rate >= 0):
            raise InputError("<priors>", "expression_rate", "a finite number >= 0", repr(self.expression_rate))
        if self.noise_rounds < 0:
            raise InputError("<priors>", "noise_rounds", "an integer >= 0", repr(self.noise_rounds))


#: The default priors (see :class:`FitPriors`).
DEFAULT_PRIORS = FitPriors()

#: Ridge weights of the photometric least squares (β in σ units, SH coefficients).
PHOTOMETRIC_REGULARISATION = {"tex": 1e-2, "sh": 1e-3}

#: Blendshapes that are correctives of another one (ICT-FaceKit: ``mouthClose`` only works on top
#: of ``jawOpen``): the fit keeps the corrective's weight at most the driver's.
CORRECTIVES = {"mouthClose": "jawOpen"}


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

    @property
    def landmark_rms_percent_iod(self) -> float:
        """``landmark_rms_px`` in % of the detected landmarks' inter-ocular distance (inf when
        that distance is 0)."""
        iod = inter_ocular_distance(self.landmarks)
        return 100.0 * self.landmark_rms_px / iod if iod > 0 else float("inf")

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


class Fitter(Protocol):
    """Anything that turns a photo into a :class:`Fit`: the seam the pipeline and the jobs fit
    through (:func:`facegeo.pipeline.reconstruct_with_fit`'s ``fitter=``,
    :func:`facegeo.jobs.fit_into_folder`). The analysis-by-synthesis :func:`fit` is the default;
    a loaded regressor (:class:`facegeo.regressor.Predictor`) is the second.

    The callers pass exactly these keywords: ``landmarks`` (None: detect them with ``detector``),
    ``camera`` (None: :meth:`Camera.for_image`'s 40° field of view) and ``photometric`` (the
    jobs' ``fit`` passes False for ``--no-photometric``; the pipeline leaves the default). The
    returned fit's ``vertices`` must be the posed mesh of ``model`` in camera space (mm) and its
    ``landmarks`` the 88 targets in the photo's pixels: the unwrap and the fit checks read them.
    """

    def __call__(self, image: np.ndarray | str | Path | Photo, model: MorphableModel | None = None,
                 landmarks: np.ndarray | None = None, detector: str | LandmarkDetector = "hybrid",
                 camera: Camera | None = None, photometric: bool = True) -> Fit:
        ...


# ---------------------------------------------------------------------------------- pose init
def _initial_pose(model: MorphableModel, targets: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(R (3,3), t (3,)) in OpenGL camera axes from solvePnP on the non-jaw iBUG points."""
    ids = INNER_FACE
    ok = np.isfinite(targets[ids]).all(axis=1)
    obj = model.mean_shape[model.landmark_indices[ids[ok]]].astype(np.float64)
    img = targets[ids[ok]].astype(np.float64)
    K = camera.matrix()
    right, left = model.mean_shape[model.landmark_indices[OUTER_EYE_CORNERS]]
    iod_model = float(np.linalg.norm(right - left))
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
    """Residuals of the landmark term over the landmark vertices, with the jaw points sliding
    along the contour (NumPy float64: Gauss–Newton squares the Jacobian, and float32 cannot tell
    the last sub-pixel decreases of the cost apart; NumPy rather than torch because the problem
    is small (176 × ~160) and has no autograd in it, so per-call overhead dominates).

    Each landmark is a point (1 − t)·S_a + t·S_b on a model edge (a = b, t = 0 for fixed points).
    The jaw contour is the model's frontal jaw polyline (landmark vertices 0→8 on the subject's
    right, 16→8 on the left); before each step every jaw point but the chin moves to the point of
    its side's projected polyline nearest to its detected position (eos's sliding contour, made
    continuous so no vertex spacing limits the fit).

    The jaw contour cannot pull expressions: the sliding contour points are moved by the current
    expression (a smile widens the lower cheeks), but that part is frozen at each step like the
    slide itself, so their residuals reach only the pose, the identity and the jaw articulation
    (blendshapes named ``jaw*``; none for PCA expression models). A detected jaw line that is
    wider or narrower than the face is explained by the identity, never by puffed cheeks or a
    stretched mouth. The chin and every other point see all expressions.
    """

    def __init__(self, model: MorphableModel, targets: np.ndarray, camera: Camera, weights: np.ndarray):
        self.model, self.camera = model, camera
        jaw = model.landmark_indices[:17]
        contours = {"right": jaw[: CHIN + 1], "left": jaw[CHIN:][::-1]}
        self.subset = np.unique(model.landmark_indices)
        position = {int(v): i for i, v in enumerate(self.subset)}
        self.mean = model.mean_shape[self.subset].astype(np.float64)
        self.id_basis = model.id_basis[:, self.subset].astype(np.float64)
        self.exp_basis = model.exp_basis[:, self.subset].astype(np.float64)
        valid = np.isfinite(targets).all(axis=1)
        w = np.where(valid, weights, 0.0).astype(np.float64)
        self.n_valid = int(np.count_nonzero(w > 0))
        self.scale = max(inter_ocular_distance(targets), 1.0)
        # relative precisions with mean 1 over the valid points, residuals in inter-ocular units
        self.sqrt_w = np.sqrt(w * self.n_valid / w.sum()) / self.scale
        self.targets = np.where(valid[:, None], targets, 0.0)
        rows = np.array([position[int(v)] for v in model.landmark_indices])
        self.rows_a, self.rows_b = rows.copy(), rows.copy()
        self.t = np.zeros(N_LANDMARKS)
        self.sliding_rows = np.array([j for j in range(17) if j != CHIN])
        self.sliding = self.sliding_rows[valid[self.sliding_rows]]
        jaw_articulation = np.array([name.startswith("jaw") for name in model.expression_names] or [False] * model.n_exp)
        self.exp_mask = np.ones((N_LANDMARKS, model.n_exp))  # which expressions move which landmark
        self.exp_mask[self.sliding_rows] = jaw_articulation
        self.contour_rows = {side: np.array([position[int(v)] for v in c]) for side, c in contours.items()}
        self.contour_vertex_rows = np.unique(np.concatenate(list(self.contour_rows.values())))
        self._update_bases(np.zeros(model.n_exp))

    def points(self, alpha: np.ndarray, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """(K, 3) model-space positions of the landmark vertices (``rows`` of them) without expression."""
        basis = self.id_basis[:, rows]
        return self.mean[rows] + (alpha @ basis.reshape(len(alpha), -1)).reshape(-1, 3)

    def _blend(self, values: np.ndarray, rows: np.ndarray | slice) -> np.ndarray:
        """(..., K, 3) per landmark vertex -> (..., len(rows), 3) on the (slid) landmark edges."""
        t = self.t[rows][:, None]
        return (1 - t) * values[..., self.rows_a[rows], :] + t * values[..., self.rows_b[rows], :]

    def _update_bases(self, delta: np.ndarray, rows: np.ndarray | slice = slice(None)) -> None:
        """The mean and bases at the 88 (slid) landmarks (only ``rows`` recomputed, after a
        slide): ``mean_lm`` (88, 3) with the frozen expression part of the contour points added,
        ``id_lm`` (n_id, 88, 3), ``exp_lm`` (n_exp, 88, 3) with the contour's mask applied."""
        if isinstance(rows, slice):
            self.mean_lm = np.zeros((N_LANDMARKS, 3))
            self.id_lm = np.zeros((self.model.n_id, N_LANDMARKS, 3))
            self.exp_lm = np.zeros((self.model.n_exp, N_LANDMARKS, 3))
        mask = self.exp_mask[rows].T[:, :, None]
        exp_full = self._blend(self.exp_basis, rows)
        frozen = (delta @ (exp_full * (1 - mask)).reshape(len(delta), -1)).reshape(-1, 3)
        self.mean_lm[rows] = self._blend(self.mean, rows) + frozen
        self.id_lm[:, rows] = self._blend(self.id_basis, rows)
        self.exp_lm[:, rows] = exp_full * mask
        self.id_flat = self.id_lm.reshape(self.model.n_id, -1)
        self.exp_flat = self.exp_lm.reshape(self.model.n_exp, -1)

    def slide_jaw(self, rotation: np.ndarray, translation: np.ndarray, alpha: np.ndarray, delta: np.ndarray) -> None:
        """Move each jaw point (but the chin) to the nearest point of its projected contour, and
        freeze the contour's expression part at ``delta``."""
        rows_all = self.contour_vertex_rows  # the contour vertices only
        shape = self.points(alpha, rows_all) + (delta @ self.exp_basis[:, rows_all].reshape(len(delta), -1)).reshape(-1, 3)
        uv = np.zeros((len(self.mean), 2))
        uv[rows_all] = project(shape, rotation, translation, self.camera)
        for side, jaw_points in (("right", np.arange(0, CHIN)), ("left", np.arange(CHIN + 1, 17))):
            rows = self.contour_rows[side]
            a, b = uv[rows[:-1]], uv[rows[1:]]  # (S, 2) segment ends
            ab = b - a
            q = self.targets[jaw_points][:, None, :]  # (P, 1, 2)
            t = np.clip(((q - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)  # (P, S)
            s = np.argmin(((a + t[..., None] * ab - q) ** 2).sum(-1), axis=1)
            self.rows_a[jaw_points], self.rows_b[jaw_points] = rows[s], rows[s + 1]
            self.t[jaw_points] = t[np.arange(len(jaw_points)), s]
        self._update_bases(delta, self.sliding_rows)

    def landmark_points(self, alpha: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """(88, 3) model-space landmark positions with the current correspondences."""
        return self.mean_lm + (alpha @ self.id_flat + delta @ self.exp_flat).reshape(N_LANDMARKS, 3)

    def projected(self, rotation: np.ndarray, translation: np.ndarray, alpha: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """(88, 2) projected landmarks with the current correspondences."""
        return project(self.landmark_points(alpha, delta), rotation, translation, self.camera)

    def residuals(self, rotation: np.ndarray, translation: np.ndarray, alpha: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """(176,) weighted landmark residuals in inter-ocular units; Σ r² = Σ w_i ‖r_i‖²."""
        diff = self.projected(rotation, translation, alpha, delta) - self.targets
        return (diff * self.sqrt_w[:, None]).reshape(-1)

    def jacobian(self, rotation: np.ndarray, translation: np.ndarray, alpha: np.ndarray, delta: np.ndarray, n_id: int, n_exp: int,
                 t_unit: float) -> np.ndarray:
        """(176, 6 + n_id + n_exp) Jacobian of :meth:`residuals` with respect to the update
        x = (ω, Δt / t_unit, Δα[:n_id], Δδ[:n_exp]) of R·exp([ω]×), t + t_unit·Δt, α, δ at x = 0.

        Written out (chain rule through the pinhole projection); a test checks it against
        central finite differences in float64."""
        p_model = self.landmark_points(alpha, delta)  # (88, 3)
        cam = p_model @ rotation.T + translation
        depth = np.maximum(-cam[:, 2], 1e-6)
        f = self.camera.focal
        dproj = np.zeros((N_LANDMARKS, 2, 3))  # d(u, v) / d(x_c, y_c, z_c)
        dproj[:, 0, 0] = f / depth
        dproj[:, 0, 2] = f * cam[:, 0] / depth**2
        dproj[:, 1, 1] = -f / depth
        dproj[:, 1, 2] = -f * cam[:, 1] / depth**2
        skew = np.zeros((N_LANDMARKS, 3, 3))
        px, py, pz = p_model.T
        skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -pz, py, -px
        skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = pz, -py, px
        to_model = dproj @ rotation  # (88, 2, 3): d(u, v) / d(model-space point)
        jac = np.empty((N_LANDMARKS, 2, 6 + n_id + n_exp))
        jac[:, :, :3] = -to_model @ skew  # X_c = R·exp([ω]×)·X: d X_c / d ω = −R·[X]×
        jac[:, :, 3:6] = t_unit * dproj
        jac[:, :, 6 : 6 + n_id] = np.einsum("vaj,kvj->vak", to_model, self.id_lm[:n_id], optimize=False)
        jac[:, :, 6 + n_id :] = np.einsum("vaj,kvj->vak", to_model, self.exp_lm[:n_exp], optimize=False)
        jac *= self.sqrt_w[:, None, None]
        return jac.reshape(2 * N_LANDMARKS, -1)

    def correspondence(self) -> np.ndarray:
        """(88,) int64: the model vertex nearest to each (slid) landmark."""
        return self.subset[np.where(self.t < 0.5, self.rows_a, self.rows_b)]


class _Prior:
    """The prior terms of E for one model and :class:`FitPriors`: scales, rates, bounds."""

    def __init__(self, model: MorphableModel, priors: FitPriors):
        blendshape = model.expression_kind == "blendshape"
        n_exp = model.n_exp
        self.exp_scale = np.full(n_exp, priors.expression_scale if blendshape else 1.0)
        self.exp_rate = np.full(n_exp, priors.expression_rate if blendshape else 0.0)
        lower, upper = model.expression_range
        self.lower, self.upper = lower.astype(np.float64), upper.astype(np.float64)
        names = list(model.expression_names)
        self.correctives = [(names.index(c), names.index(d)) for c, d in CORRECTIVES.items() if c in names and d in names]

    def project(self, delta: np.ndarray) -> np.ndarray:
        """δ clipped into its range, each corrective at most its driver (a new array)."""
        delta = np.clip(delta, self.lower, self.upper)
        for c, d in self.correctives:
            delta[c] = min(delta[c], delta[d])
        return delta


def _rotation(omega: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of the axis·angle vector ``omega`` (radians), by OpenCV's Rodrigues."""
    return cv2.Rodrigues(omega)[0]


def _levenberg_marquardt(problem: _LandmarkProblem, state: dict[str, np.ndarray], stage: LandmarkStage, prior: _Prior,
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
    t_unit = 10.0  # mm per unit of the translation parameter (keeps the system well scaled)
    id_cols, exp_cols = slice(6, 6 + n_id), slice(6 + n_id, 6 + n_id + n_exp)
    inv_var = prior.exp_scale**-2

    def unpack(x: np.ndarray) -> tuple[np.ndarray, ...]:
        rot = state["rotation"] @ _rotation(x[:3])
        trans = state["translation"] + t_unit * x[3:6]
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
    for _ in range(stage.iterations):
        problem.slide_jaw(state["rotation"], state["translation"], state["alpha"], state["delta"])
        r0, cost0 = cost(state["rotation"], state["translation"], state["alpha"], state["delta"])
        jac = problem.jacobian(state["rotation"], state["translation"], state["alpha"], state["delta"], n_id, n_exp, t_unit) / noise
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
        for _attempt in range(8):
            step = np.zeros(n)
            step[free] = np.linalg.solve(h + np.diag(damping * diag), -g)
            rot, trans, alpha, delta = unpack(step)
            _, cost1 = cost(rot, trans, alpha, delta)
            if np.isfinite(cost1) and cost1 < cost0:
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


def _estimate_noise(problem: _LandmarkProblem, state: dict[str, np.ndarray], prior: _Prior, noise: float) -> tuple[float, float]:
    """(σ, p_eff): the landmark noise re-estimated from the residuals (:class:`FitPriors`)."""
    model = problem.model
    problem.slide_jaw(state["rotation"], state["translation"], state["alpha"], state["delta"])
    r = problem.residuals(state["rotation"], state["translation"], state["alpha"], state["delta"])
    jac = problem.jacobian(state["rotation"], state["translation"], state["alpha"], state["delta"], model.n_id, model.n_exp, 10.0)
    d = state["delta"]
    free = np.ones(jac.shape[1], dtype=bool)
    free[6 + model.n_id :] = (d > prior.lower + 1e-9) & (d < prior.upper - 1e-9)
    a = jac[:, free]
    data = a.T @ a / noise**2
    precision = np.concatenate([np.zeros(6), np.ones(model.n_id), prior.exp_scale**-2])[free]
    p_eff = float(np.trace(np.linalg.solve(data + np.diag(precision), data)))
    n_obs = 2 * problem.n_valid - len(problem.sliding)  # a sliding point only constrains its normal
    return float(np.sqrt(float(r @ r) / max(n_obs - p_eff, 1.0))), p_eff


def fit_landmarks(
    model: MorphableModel,
    landmarks: np.ndarray | torch.Tensor,
    camera: Camera,
    weights: np.ndarray | None = None,
    schedule: tuple[LandmarkStage, ...] = LANDMARK_SCHEDULE,
    priors: FitPriors = DEFAULT_PRIORS,
    init: Fit | None = None,
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
    Returns:
        A :class:`Fit` with β = 0 and γ = ambient white (no photometric stage);
        ``info["landmark_noise"]`` holds the estimated noise (px and inter-ocular fraction),
        the effective number of parameters and the expression weights held at a bound.
    """
    targets = np.asarray(landmarks.detach().cpu().numpy() if isinstance(landmarks, torch.Tensor) else landmarks, dtype=np.float64)
    if targets.shape != (N_LANDMARKS, 2):
        raise InputError("<landmarks>", "landmarks", f"shape ({N_LANDMARKS}, 2) in pixels", str(targets.shape))
    valid = np.isfinite(targets).all(axis=1)
    if valid[INNER_FACE].sum() < 6:
        raise InputError("<landmarks>", "landmarks", "at least 6 finite non-jaw iBUG points",
                         f"{int(valid[INNER_FACE].sum())}")
    weights = LANDMARK_WEIGHTS if weights is None else np.asarray(weights, dtype=np.float32)
    if weights.shape != (N_LANDMARKS,) or not np.all(np.isfinite(weights)) or np.any(weights < 0):
        raise InputError("<weights>", "weights", f"({N_LANDMARKS},) finite, non-negative", str(weights.shape))
    check_landmarks(targets, camera)

    with threadpool_limits(limits=LANDMARK_FIT_THREADS, user_api="blas"):
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        prior = _Prior(model, priors)
        if init is None:
            rotation, translation = _initial_pose(model, targets, camera)
            alpha, delta = np.zeros(model.n_id), np.zeros(model.n_exp)
        else:
            rotation, translation, alpha, delta = init.rotation, init.translation, init.alpha, init.delta
        timings["pose_init"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        problem = _LandmarkProblem(model, targets, camera, weights)
        state = {
            "rotation": np.array(rotation, dtype=np.float64),
            "translation": np.array(translation, dtype=np.float64),
            "alpha": np.array(alpha, dtype=np.float64),
            "delta": prior.project(np.array(delta, dtype=np.float64)),
        }
        noise = priors.noise
        steps = {stage.name: _levenberg_marquardt(problem, state, stage, prior, noise) for stage in schedule[:-1]}
        history = [noise]
        p_eff = float("nan")
        last = schedule[-1]
        for round_ in range(priors.noise_rounds + 1):
            if round_ > 0 or len(schedule) > 1:  # the noise is estimated once some shape is fitted
                estimate, p_eff = _estimate_noise(problem, state, prior, noise)
                estimate = max(estimate, priors.noise_floor)
                if round_ > 0 and abs(np.log(estimate / noise)) < NOISE_TOLERANCE:
                    break
                noise = estimate
                history.append(noise)
            stage = last if round_ == 0 else LandmarkStage(last.name, max(last.iterations // 2, 1), last.n_id, last.expression)
            steps[f"{last.name}@{noise:.4f}"] = _levenberg_marquardt(problem, state, stage, prior, noise)
        problem.slide_jaw(state["rotation"], state["translation"], state["alpha"], state["delta"])
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
    return _assemble(model, problem, state, camera, targets, timings, info)


#: BLAS threads for the landmark fit's small (176 × ~160) linear algebra: on a loaded 2-core
#: machine more threads made it 5–15× slower for identical results (benchmarks/bench_fit_speed.py,
#: results in benchmarks/RESULTS.md).
LANDMARK_FIT_THREADS = 1


def _assemble(
    model: MorphableModel,
    problem: _LandmarkProblem,
    state: dict[str, np.ndarray],
    camera: Camera,
    targets: np.ndarray,
    timings: dict[str, float],
    info: dict[str, Any],
) -> Fit:
    fitted = problem.projected(state["rotation"], state["translation"], state["alpha"], state["delta"])
    with torch.no_grad():
        shape_vertices = model.shape(torch.from_numpy(state["alpha"]).float(), torch.from_numpy(state["delta"]).float()).numpy()
    rotation, translation = state["rotation"].astype(np.float32), state["translation"].astype(np.float32)
    vertices = shape_vertices @ rotation.T + translation
    errors = np.linalg.norm(fitted - targets, axis=1)
    valid = np.isfinite(errors)
    return Fit(
        alpha=state["alpha"].astype(np.float32),
        delta=state["delta"].astype(np.float32),
        beta=np.zeros(model.n_tex, dtype=np.float32),
        gamma=AMBIENT_WHITE.numpy().copy(),
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


# ---------------------------------------------------------------------------------- photometric
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
    observed = torch.from_numpy(sample_bilinear(image_linear, uv)).double()
    basis = sh_basis(torch.from_numpy(normals[use]).double())  # (N, 9)
    mean_albedo = model.tensor("mean_albedo", torch.float64)[use]
    tex_basis = model.tensor("tex_basis", torch.float64)[:, use] if model.n_tex else None
    beta = torch.zeros(model.n_tex, dtype=torch.float64)
    gamma = AMBIENT_WHITE.double().clone()
    inliers = torch.ones(len(use), dtype=torch.bool)
    sh_ridge = torch.full((N_SH,), PHOTOMETRIC_REGULARISATION["sh"], dtype=torch.float64)
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
            reg = PHOTOMETRIC_REGULARISATION["tex"] * len(rhs) * torch.eye(model.n_tex, dtype=torch.float64)
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
    init: Fit | None = None,
    priors: FitPriors = DEFAULT_PRIORS,
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
        init: start the landmark fit from this fit's pose, α and δ (e.g. a regressor's
            prediction) instead of solvePnP on the mean shape.
        priors: the landmark fit's priors (:class:`FitPriors`).
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
    result = fit_landmarks(model, landmarks, camera, priors=priors, init=init)
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
