"""The knobs of the landmark fit: its priors and noise model (:class:`FitPriors`), the
coarse-to-fine schedule (:class:`LandmarkStage`), and which blendshapes are correctives."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facegeo.errors import InputError

__all__ = ["FitPriors", "DEFAULT_PRIORS", "LandmarkStage", "LANDMARK_SCHEDULE", "CORRECTIVES"]



@dataclass(frozen=True)
class LandmarkStage:
    """One coarse-to-fine stage: Levenberg–Marquardt ``iterations`` with the pose, the first
    ``n_id`` identity components (None: all) and, if ``expression``, all expression components;
    the jaw and outline points slide to the model's contours (:meth:`~facegeo.fitting.landmark_problem.LandmarkProblem.slide`)
    before each of the first ``slides`` iterations (None: before every one)."""

    name: str
    iterations: int
    n_id: int | None
    expression: bool
    slides: int | None = None


#: The documented coarse-to-fine schedule of the landmark stage (error against iterations in
#: benchmarks/RESULTS.md). The last stage is repeated after each re-estimation of the noise
#: level (:class:`FitPriors`).
LANDMARK_SCHEDULE: tuple[LandmarkStage, ...] = (
    LandmarkStage("pose", 6, 0, False),
    LandmarkStage("coarse", 6, 20, True),
    LandmarkStage("fine", 12, None, True),
)



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
    #: Expressions (the model's names; names it lacks are ignored) held at 0: what the landmarks
    #: cannot tell apart from another expression (a blendshape model's gaze, which moves the lids,
    #: for a fit without the irises).
    held_expressions: tuple[str, ...] = ()
    #: Expressions held at values measured by other means, as (name, value) pairs (names the model
    #: lacks are ignored; values are clipped into the model's range): a tracker's blinks read from
    #: the lids (:mod:`facegeo.landmarks.eyelids`).
    measured_expressions: tuple[tuple[str, float], ...] = ()
    #: A brow landmark's noise along its brow over its noise across it (dlib's 17-21 and 22-26,
    #: :class:`~facegeo.fitting.landmark_problem.LandmarkProblem`): a detector finds a brow, a
    #: long edge, across it and spaces its points along it by its shape prior (the aperture
    #: problem; on a lowered brow dlib's points move down as a row while the model's also close
    #: in). 1: the same both ways.
    brow_along_noise: float = 1.0

    def __post_init__(self) -> None:
        for name in ("noise", "noise_floor", "expression_scale", "brow_along_noise"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError("<priors>", name, "a finite number > 0", repr(value))
        if not (np.isfinite(self.expression_rate) and self.expression_rate >= 0):
            raise InputError("<priors>", "expression_rate", "a finite number >= 0", repr(self.expression_rate))
        for name, value in self.measured_expressions:
            if not np.isfinite(value):
                raise InputError("<priors>", f"measured_expressions[{name!r}]", "a finite number", repr(value))
        if self.noise_rounds < 0:
            raise InputError("<priors>", "noise_rounds", "an integer >= 0", repr(self.noise_rounds))


#: The default priors (see :class:`FitPriors`).
DEFAULT_PRIORS = FitPriors()


#: Blendshapes that are correctives of another one (ICT-FaceKit: ``mouthClose`` only works on top
#: of ``jawOpen``): the fit keeps the corrective's weight at most the driver's.
CORRECTIVES = {"mouthClose": "jawOpen"}
