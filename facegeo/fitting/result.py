"""The result of a fit and the seam fitters plug into: :class:`Fit`, :class:`Fitter`.

Data only (NumPy; no solver, no OpenCV or torch at import), so modules that read or write fits
(the overlay, the texturing context, the preview, the regressor) do not import the solver.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from facegeo.camera import Camera, euler_from_rotation
from facegeo.landmarks.scheme import inter_ocular_distance

if TYPE_CHECKING:
    from facegeo.landmarks.detectors import LandmarkDetector
    from facegeo.morphable_model import MorphableModel
    from facegeo.photo import Photo

__all__ = ["Fit", "Fitter"]


@dataclass(frozen=True)
class Fit:
    """The result of a fit. Arrays are NumPy float32 unless stated. Frozen: a stage that changes
    a fit makes a new one (``dataclasses.replace``); its ``timings`` and ``info`` dicts take the
    records later stages add (notes, the checks' figures).

    alpha (n_id,), delta (n_exp,), beta (n_tex,): coefficients in σ units (δ: blendshape weights
    for ICT). gamma (3, 9): SH coefficients per RGB channel (total, no hidden offset).
    rotation (3, 3), translation (3,) mm: X_c = R·X + t. camera: the intrinsics used.
    vertices (V, 3): posed, camera space, mm. shape_vertices (V, 3): model space, unposed, mm.
    landmarks (88, 2) px: the targets; landmarks_fitted (88, 2) px: the model's projections with
    the final (slid) correspondences ``landmark_vertices`` (88,) int64.
    landmark_errors_px (88,): per-point distance; landmark_rms_px: their RMS over the points the
    fit used (finite, weight > 0: with dense landmarks the jaw's sliding points are not used).
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
